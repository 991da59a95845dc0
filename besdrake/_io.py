"""Safe output files shared by every stage: atomic writes (a temporary file in the same folder, then
``os.replace``), JSON without pickle, and the rule that an output never replaces an input."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any, Iterator

import numpy as np

_UMASK = os.umask(0)
os.umask(_UMASK)


class OutputError(ValueError):
    """An output path that cannot be written: it is one of the inputs, or its folder is missing."""


def json_default(obj: Any) -> Any:
    """``json.dumps`` fallback for numpy arrays and scalars and for paths."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve() or (a.exists() and b.exists() and os.path.samefile(a, b))
    except OSError:
        return False


def check_output(out: str | Path, inputs: list[str | Path] = (), make_parents: bool = False) -> Path:
    """``out`` as a Path after checking that it is none of ``inputs`` and that its folder exists
    (created when ``make_parents``); :class:`OutputError` otherwise."""
    out = Path(out)
    for p in inputs:
        if p is not None and _same_file(out, Path(p)):
            raise OutputError(f"the output {out} is an input file; refusing to overwrite it (choose another output path)")
    parent = out.parent
    if make_parents:
        parent.mkdir(parents=True, exist_ok=True)
    elif not parent.is_dir():
        raise OutputError(f"cannot write {out}: the folder {parent} does not exist")
    return out


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path in ``path``'s folder; on success it replaces ``path`` (``os.replace``), on an
    exception it is removed. A killed run never leaves a half-written ``path``."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~_UMASK)  # mkstemp makes 0600; outputs get the usual mode
        os.replace(tmp_path, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()


def write_text(path: str | Path, text: str, make_parents: bool = True) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    path = Path(path)
    if make_parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


def write_bytes(path: str | Path, data: bytes, make_parents: bool = True) -> Path:
    """Write ``data`` to ``path`` atomically."""
    path = Path(path)
    if make_parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return path


def write_json(path: str | Path, data: Any) -> Path:
    """Write ``data`` as JSON atomically: a temporary file beside ``path``, then a rename, so a killed
    run never leaves a half-written file."""
    return write_text(path, json.dumps(data, indent=1, default=json_default))


def save_figure(fig: Any, path: str | Path, **kwargs: Any) -> Path:
    """``fig.savefig`` atomically (the format from ``path``'s extension)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    kwargs.setdefault("format", path.suffix.lstrip(".") or "png")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, **kwargs)
    return path


def save_npz(path: str | Path, compressed: bool = True, **arrays: Any) -> Path:
    """``np.savez[_compressed]`` atomically (``path`` is used as given, no ``.npz`` appended)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        (np.savez_compressed if compressed else np.savez)(f, **arrays)
    return path
