"""Manual segmentations stored beside a recording (``*_manually_segmented.json``).

The layout is a JSON list of ``{"start index": F0, "end index": F1, "label": NAME}`` with
``F0``/``F1`` in the recording file's own ``Frame`` numbering.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from besdrake.mocap.recording import MocapFormatError


@dataclass(frozen=True)
class Segment:
    """One labelled movement segment, borders in the file's frame numbering (inclusive)."""

    start_frame: int
    end_frame: int
    label: str

    def to_json(self) -> dict:
        return {"start index": int(self.start_frame), "end index": int(self.end_frame), "label": self.label}


def segmentation_path(recording_path: str | Path) -> Path:
    """``<stem>_manually_segmented.json`` beside ``recording_path``."""
    p = Path(recording_path)
    return p.with_name(p.stem + "_manually_segmented.json")


def read_segmentation(path: str | Path) -> list[Segment]:
    """Read a ``*_manually_segmented.json`` file into segments (in file order)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise MocapFormatError(f"{path}: not valid JSON ({err})") from None
    if not isinstance(data, list):
        raise MocapFormatError(f"{path}: expected a JSON list of segments, got {type(data).__name__}")
    segments = []
    for i, item in enumerate(data):
        try:
            start, end, label = item["start index"], item["end index"], item["label"]
        except (KeyError, TypeError):
            raise MocapFormatError(
                f"{path}: segment {i} needs the keys 'start index', 'end index' and 'label', got {item!r}"
            ) from None
        if not all(isinstance(v, (int, float)) and float(v).is_integer() for v in (start, end)):
            raise MocapFormatError(f"{path}: segment {i} has non-integer frame indices {start!r}, {end!r}")
        if end < start:
            raise MocapFormatError(f"{path}: segment {i} ends ({end}) before it starts ({start})")
        segments.append(Segment(int(start), int(end), str(label)))
    return segments


def write_segmentation(segments: list[Segment], path: str | Path) -> None:
    """Write segments in the ``*_manually_segmented.json`` layout."""
    Path(path).write_text(json.dumps([s.to_json() for s in segments]))
