"""A run folder that a person can read and a program can resume.

Layout::

    RUN/
      config.yaml          the effective configuration (written once; a resume must match it, but for settings a
                           later besdrake added: the run goes on with its own configuration, as it began)
      inputs.json          SHA-256 of every input file (recordings, lab, scenario)
      NN_stage/            one folder per stage, in order
        stage.json         written last: the stage's summary and wall time (its presence = done)
        ...                the stage's outputs (JSON, CSV, NPZ, PNG, HTML)
      report.md            written by the report stage

A stage whose ``stage.json`` exists is skipped on a rerun: Ctrl-C leaves a resumable run, and stages
that resume internally (policy search, lab logs) continue where they stopped.
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path
from typing import Any

import yaml

from besdrake._io import write_text as _atomic_write_text
from besdrake._io import write_json


class RunError(ValueError):
    """A run folder that belongs to another configuration."""


def file_hash(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def settings_added(stored: Any, new: Any, prefix: str = "") -> list[str] | None:
    """The dotted keys ``new`` has and ``stored`` lacks where every setting ``stored`` has is the same in ``new`` (a
    configuration that a later besdrake only added settings to), else None."""
    if not (isinstance(stored, dict) and isinstance(new, dict)):
        return [] if stored == new else None
    if not set(stored) <= set(new):
        return None
    added = [f"{prefix}{k}" for k in new if k not in stored]
    for k in stored:
        inner = settings_added(stored[k], new[k], f"{prefix}{k}.")
        if inner is None:
            return None
        added += inner
    return added


class RunFolder:
    """The folder of one ``besdrake learn`` run. A run begun by an earlier besdrake whose configuration lacks only
    settings added since goes on with its own configuration (each stage reads a missing setting as the behaviour
    before it); :attr:`settings_left_out` names them."""

    def __init__(self, root: str | Path, config: dict[str, Any]) -> None:
        self.root = Path(root)
        self.config = config
        self.settings_left_out: list[str] = []
        self.root.mkdir(parents=True, exist_ok=True)
        path = self.root / "config.yaml"
        text = yaml.safe_dump(config, sort_keys=False)
        if path.is_file():
            stored, new = yaml.safe_load(path.read_text()), yaml.safe_load(text)
            if stored != new:
                added = settings_added(stored, new)
                if not added:
                    raise RunError(
                        f"{self.root} holds a run with another configuration; resume it with the same options, "
                        "or choose a new --out folder"
                    )
                self.config, self.settings_left_out = stored, added
        else:
            _atomic_write_text(path, text)

    def record_inputs(self, files: dict[str, Path]) -> None:
        """Hash the input files; a resume with changed inputs is refused."""
        hashes = {name: file_hash(p) for name, p in files.items() if Path(p).is_file()}
        path = self.root / "inputs.json"
        if path.is_file():
            before = json.loads(path.read_text())
            changed = [k for k in hashes if k in before and before[k] != hashes[k]]
            if changed:
                raise RunError(f"input files changed since the run started: {changed}; use a new --out folder")
            hashes = before | hashes
        write_json(path, hashes)

    def stage_dir(self, index: int, name: str) -> Path:
        d = self.root / f"{index:02d}_{name}"
        d.mkdir(parents=True, exist_ok=True)
        return d

    def done(self, index: int, name: str) -> dict[str, Any] | None:
        """The finished stage's record, None if it has not finished. :class:`RunError` when its files were
        changed or deleted since it finished (checksums in ``stage.json``)."""
        folder = self.root / f"{index:02d}_{name}"
        path = folder / "stage.json"
        if not path.is_file():
            return None
        try:
            record = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
            raise RunError(f"{path} is not valid JSON ({err}); delete the folder {folder} to redo the stage") from None
        for rel, digest in (record.get("files") or {}).items():
            f = folder / rel
            if not f.is_file() or file_hash(f) != digest:
                what = "was deleted" if not f.is_file() else "was changed"
                raise RunError(f"{f} {what} after the stage finished (SHA-256 in stage.json): delete the folder {folder} "
                               "to redo the stage (and the later ones), or choose a new --out folder")
        return record

    def mark_done(self, index: int, name: str, summary: dict[str, Any], seconds: float) -> dict[str, Any]:
        folder = self.stage_dir(index, name)
        files = {str(p.relative_to(folder)): file_hash(p) for p in sorted(folder.rglob("*"))
                 if p.is_file() and p.name != "stage.json" and not p.name.endswith((".lock", ".tmp"))}
        record = {"stage": name, "seconds": seconds, "finished": time.strftime("%Y-%m-%dT%H:%M:%S"), "summary": summary,
                  "files": files}
        write_json(self.stage_dir(index, name) / "stage.json", record)
        return record
