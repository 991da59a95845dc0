"""Save and load any DMP of this package as JSON (the ``type`` field selects the class)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from besdrake._io import write_text as _atomic_write_text
from besdrake.imitation._validation import DMPParameterError
from besdrake.imitation.cartesian import CartesianDMP
from besdrake.imitation.dmp import DMP
from besdrake.imitation.orientation import QuaternionDMP

_CLASSES = {"DMP": DMP, "QuaternionDMP": QuaternionDMP, "CartesianDMP": CartesianDMP}


def save_dmp(dmp: DMP | QuaternionDMP | CartesianDMP, path: str | Path) -> Path:
    """Write ``dmp`` as JSON (SI units) and return the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _atomic_write_text(path, json.dumps(dmp.to_dict(), indent=1))
    return path


def _read_dmp_json(path: str | Path) -> dict[str, Any]:
    """The JSON object in ``path``; :class:`DMPParameterError` for a missing, corrupt or non-object file."""
    path = Path(path)
    if not path.is_file():
        raise DMPParameterError(f"DMP file not found: {path}")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise DMPParameterError(f"DMP file {path} is not valid JSON: {err}") from err
    if not isinstance(data, dict):
        raise DMPParameterError(f"DMP file {path} does not describe a DMP (a JSON {type(data).__name__}, not an object)")
    return data


def load_dmp(path: str | Path) -> DMP | QuaternionDMP | CartesianDMP:
    """Read a DMP written by :func:`save_dmp`; :class:`DMPParameterError` for a missing or corrupt file."""
    data = _read_dmp_json(path)
    if data.get("type") not in _CLASSES:
        raise DMPParameterError(f"DMP file {path} does not describe a DMP (type {data.get('type')!r}; expected one of {sorted(_CLASSES)})")
    return _CLASSES[data["type"]].from_dict(data)
