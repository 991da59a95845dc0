#!/usr/bin/env python3
"""Render the Diagram of every scenario in diagrams/ as GraphViz: always the .dot text, and an SVG and a PNG
when the ``dot`` program is installed. Usage: ``python3 scripts/render_diagrams.py [--out diagrams/graphs]``."""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from pathlib import Path

from besdrake.sim.diagram import build_diagram
from besdrake.sim.scenario import DIAGRAMS_DIR, load_scenario


def render(scenario_path: Path, out_dir: Path, max_depth: int = 1) -> list[Path]:
    """Write ``<name>.dot`` (and .svg/.png with GraphViz) for one scenario; returns the written paths."""
    scen = load_scenario(scenario_path)
    handles = build_diagram(scen)
    dot_text = handles.diagram.GetGraphvizString(max_depth=max_depth)
    out_dir.mkdir(parents=True, exist_ok=True)
    dot_path = out_dir / f"{scen.name}.dot"
    dot_path.write_text(dot_text)
    written = [dot_path]
    dot = shutil.which("dot")
    if dot:
        for fmt in ("svg", "png"):
            target = out_dir / f"{scen.name}.{fmt}"
            subprocess.run([dot, f"-T{fmt}", str(dot_path), "-o", str(target)], check=True)
            written.append(target)
    return written


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default=str(DIAGRAMS_DIR / "graphs"), help="output folder")
    ap.add_argument("scenarios", nargs="*", help="scenario YAML files (default: all in diagrams/)")
    args = ap.parse_args(argv)
    paths = [Path(p) for p in args.scenarios] or sorted(DIAGRAMS_DIR.glob("*.yaml"))
    for p in paths:
        for w in render(p, Path(args.out)):
            print(w)
    if not shutil.which("dot"):
        print("note: GraphViz 'dot' not found; wrote .dot text only", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
