"""Fuzz every input format the CLI reads: seeded mutations, run in-process through ``besdrake.cli.main``.

Each case writes one mutated input file (TSV, C3D, plan JSON, scenario YAML, lab YAML, learn config YAML,
effect plugin, a recording in a ``learn --demonstrations`` folder, a robot YAML of ``besdrake/models``) into a fresh folder, runs the command that reads it and checks:

* the run ends with exit 0 (or 1: ``simulate``'s flagged failed simulation) or exit 2 with exactly one
  ``besdrake: error:`` line -- never an exception escaping ``main`` and never the last-resort
  ``internal error`` (both count as ``tracebacks``);
* every input file is byte-identical afterwards (``modified_inputs``).

    python scripts/bench_fuzz.py                 # 2,700 cases (300 per format), JSON counts
    python scripts/bench_fuzz.py --per-format 20 --json
    python scripts/bench_fuzz.py --formats robot_yaml --per-format 300
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import math
import random
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

BAD_VALUES: list[Any] = [None, -1, 0, 1e308, -1e308, "nan", "inf", "x", "", [], {}, [1, 2], True, 3600, 1e-9, -0.0, "null"]
BAD_TOKENS = ["nan", "-1", "1e308", "", "null", "abc", "-0", "1e-9", "3600", "inf", "0", "99999999999", "\t", "é", "1,5"]


# ---------------------------------------------------------------------------------------- mutators


def _mutate_text(text: str, rng: random.Random) -> str:
    """One or two random edits of a text: lines, tokens, bytes, truncation, number scale."""
    lines = text.split("\n")
    for _ in range(rng.choice((1, 1, 2))):
        kind = rng.randrange(9)
        i = rng.randrange(len(lines)) if lines else 0
        if kind == 0 and lines:
            del lines[i]
        elif kind == 1 and lines:
            lines.insert(i, lines[i])
        elif kind == 2 and lines:
            toks = lines[i].split("\t") if "\t" in lines[i] else lines[i].split(" ")
            if toks:
                toks[rng.randrange(len(toks))] = rng.choice(BAD_TOKENS)
                lines[i] = ("\t" if "\t" in lines[i] else " ").join(toks)
        elif kind == 3:
            joined = "\n".join(lines)
            return joined[: rng.randrange(len(joined) + 1)]
        elif kind == 4 and lines:
            j = rng.randrange(len(lines))
            lines[i], lines[j] = lines[j], lines[i]
        elif kind == 5 and lines:
            line = lines[i]
            if line:
                k = rng.randrange(len(line))
                lines[i] = line[:k] + chr(rng.randrange(32, 127)) + line[k + 1 :]
        elif kind == 6 and lines:
            factor = rng.choice((10.0, 0.1, 1000.0, -1.0))
            out = []
            for tok in lines[i].split("\t"):
                try:
                    out.append(repr(float(tok) * factor))
                except ValueError:
                    out.append(tok)
            lines[i] = "\t".join(out)
        elif kind == 7:
            return ""
        else:
            lines = lines[: max(1, len(lines) // rng.choice((2, 3, 10)))]
    return "\n".join(lines)


def _paths(obj: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix]
    if isinstance(obj, dict):
        for k, v in obj.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(obj, list) and len(obj) <= 12:
        for k, v in enumerate(obj):
            out += _paths(v, prefix + (k,))
    elif isinstance(obj, list) and obj:
        out += _paths(obj[0], prefix + (0,)) + _paths(obj[-1], prefix + (len(obj) - 1,))
    return out


def _mutate_tree(data: Any, rng: random.Random) -> Any:
    """Replace, delete or add a value at a random place of a JSON/YAML tree."""
    import copy

    data = copy.deepcopy(data)
    for _ in range(rng.choice((1, 1, 2))):
        paths = [p for p in _paths(data) if p]
        if not paths:
            return rng.choice(BAD_VALUES)
        path = rng.choice(paths)
        parent = data
        for k in path[:-1]:
            parent = parent[k]
        key = path[-1]
        kind = rng.randrange(5)
        if kind == 0 and isinstance(parent, dict):
            del parent[key]
        elif kind == 1 and isinstance(parent, dict):
            parent["unknown_" + str(rng.randrange(100))] = rng.choice(BAD_VALUES)
        elif kind == 2 and isinstance(parent[key], (int, float)) and not isinstance(parent[key], bool):
            parent[key] = parent[key] * rng.choice((10.0, -1.0, 1e6, 0.0, 1e-6))
        else:
            parent[key] = rng.choice(BAD_VALUES)
    return data


def _mutate_bytes(data: bytes, rng: random.Random) -> bytes:
    """Byte flips (mostly in the header and parameter section), truncation or garbage."""
    b = bytearray(data)
    kind = rng.randrange(4)
    if kind == 0:
        return bytes(b[: rng.randrange(len(b) + 1)])
    if kind == 3:
        return bytes(rng.randrange(256) for _ in range(rng.randrange(1, 2048)))
    span = min(len(b), 2048) if kind == 1 else len(b)
    for _ in range(rng.randrange(1, 8)):
        b[rng.randrange(span)] = rng.randrange(256)
    return bytes(b)


# ---------------------------------------------------------------------------------------- seeds


@dataclass
class Seeds:
    """Valid inputs of every format, made once in ``root``."""

    root: Path
    files: dict[str, Path] = field(default_factory=dict)


def make_seeds(root: Path) -> Seeds:
    """A small synthetic recording (labelled, unlabelled, C3D), the default throw's plan, the nominal
    scenario, the default lab, a quick learn config and a drag-effect plugin."""
    import numpy as np

    from besdrake.mocap.c3d_io import write_c3d
    from besdrake.mocap.qualisys import read_tsv, write_tsv
    from besdrake.tasks.throwing.demonstrator import generate_dataset
    from besdrake.sim.scenario import DIAGRAMS_DIR
    from besdrake.tasks.throwing.throws import default_throw

    s = Seeds(root)
    generate_dataset(root / "syn", n_subjects=1, n_experiments=1, n_throws=2, seed=0)
    rec = read_tsv(next((root / "syn").glob("*.tsv")))
    rec = rec.crop(int(rec.frames[0]), int(rec.frames[0]) + 299)
    write_tsv(rec, root / "rec.tsv")
    write_c3d(rec, root / "rec.c3d")
    unl = read_tsv(next((root / "syn" / "unlabeled").glob("*.tsv")))
    write_tsv(unl.crop(int(unl.frames[0]), int(unl.frames[0]) + 299), root / "unl.tsv")
    default_throw().save(root / "plan.json")
    shutil.copy(DIAGRAMS_DIR / "nominal.yaml", root / "scenario.yaml")
    shutil.copy(DIAGRAMS_DIR / "labs" / "default_lab.yaml", root / "lab.yaml")
    (root / "config.yaml").write_text((REPO / "besdrake" / "tasks" / "throwing" / "learn.yaml").read_text().split("\nquick:")[0] + "\n")
    (root / "plugin.py").write_text(PLUGIN)
    robot_seeds(root)
    s.files = {p.stem if p.suffix != ".c3d" else "c3d": p for p in root.iterdir() if p.is_file()}
    del np
    return s


PLUGIN = '''from besdrake.sim.effects import Effect, Param, register_effect


@register_effect
class FuzzDrag(Effect):
    """Fuzzer plugin: air drag on the ball in flight."""
    name = "EFFECT_NAME"
    applied_via = "flight"
    params = {"cd": Param(0.1, 0.0, 1.0, "1", "drag coefficient")}

    def apply(self, setup, values):
        setup.drag_coefficient = values["cd"]
'''

PLUGIN_EDITS = [
    ("        setup.drag_coefficient = values[\"cd\"]", "        raise RuntimeError('boom')"),
    ("        setup.drag_coefficient = values[\"cd\"]", "        import sys; sys.exit(3)"),
    ("        setup.drag_coefficient = values[\"cd\"]", "        setup.drag_coefficient = 1 / 0"),
    ("        setup.drag_coefficient = values[\"cd\"]", "        setup.no_such_field = values['cd']"),
    ("@register_effect", "import sys\nsys.exit(3)\n@register_effect"),
    ("@register_effect", "raise ValueError('import fails')\n@register_effect"),
    ("Param(0.1, 0.0, 1.0", "Param(5.0, 0.0, 1.0"),
    ("applied_via = \"flight\"", "applied_via = \"nowhere\""),
]


ROBOTS = ("compi", "compi", "compi", "iiwa14", "panda")  # the throwing robot most often: its mutants reach the simulation


def robot_seeds(root: Path) -> dict[str, Path]:
    """The packaged robot files (``besdrake/models/*/robot.yaml``), comments kept, their model file made absolute
    (so that a mutant written elsewhere still finds its URDF)."""
    import re

    from besdrake.sim.scenario import MODELS_DIR

    out = {}
    for name in sorted(set(ROBOTS)):
        src = MODELS_DIR / name / "robot.yaml"
        text = re.sub(r"^(\s+file:\s*)([^\s#]+)", lambda m: m.group(1) + (m.group(2) if "://" in m.group(2) else str(src.parent / m.group(2))),
                      src.read_text(), count=1, flags=re.M)
        out[name] = root / f"robot_{name}.yaml"
        out[name].write_text(text)
    return out


# ---------------------------------------------------------------------------------------- cases


def _yaml_mutant(path: Path, rng: random.Random) -> str:
    import yaml

    if rng.random() < 0.3:
        return _mutate_text(path.read_text(), rng)
    return yaml.safe_dump(_mutate_tree(yaml.safe_load(path.read_text()), rng), sort_keys=False)


def _json_mutant(path: Path, rng: random.Random) -> str:
    if rng.random() < 0.3:
        return _mutate_text(path.read_text(), rng)
    return json.dumps(_mutate_tree(json.loads(path.read_text()), rng), allow_nan=True)


def case_tsv(s: Seeds, d: Path, rng: random.Random) -> tuple[list[str], list[Path]]:
    which = rng.choice(("rec", "unl"))
    f = d / f"{which}.tsv"
    f.write_text(_mutate_text(s.files[which].read_text(), rng))
    if which == "rec" and rng.random() < 0.6:
        return ["segment", str(f), "--json"], [f]
    ref = d / "ref.tsv"
    shutil.copy(s.files["rec"], ref)
    return ["mocap", "label", str(f), "--reference", str(ref), "--out", str(d / "out.tsv")], [f, ref]


def case_demonstrations(s: Seeds, d: Path, rng: random.Random) -> tuple[list[str], list[Path]]:
    """``learn --demonstrations`` on a folder with one mutated recording (TSV or C3D): its label stage."""
    folder = d / "demos"
    folder.mkdir()
    if rng.random() < 0.5:
        f = folder / "rec.tsv"
        f.write_text(_mutate_text(s.files["rec"].read_text(), rng))
    else:
        f = folder / "rec.c3d"
        f.write_bytes(_mutate_bytes(s.files["c3d"].read_bytes(), rng))
    return ["learn", "--quick", "--demonstrations", str(folder), "--out", str(d / "run"), "--stage", "label", "--json"], [f]


def case_c3d(s: Seeds, d: Path, rng: random.Random) -> tuple[list[str], list[Path]]:
    f = d / "rec.c3d"
    f.write_bytes(_mutate_bytes(s.files["c3d"].read_bytes(), rng))
    return ["segment", str(f), "--json"], [f]


def case_plan(s: Seeds, d: Path, rng: random.Random) -> tuple[list[str], list[Path]]:
    f = d / "throw.plan.json"
    f.write_text(_json_mutant(s.files["plan"], rng))
    if rng.random() < 0.7:
        return ["simulate", "--plan", str(f), "--json"], [f]
    return ["lab", "run", "--lab", "ideal_lab", "--plans", str(f), "--out", str(d / "log"), "--quiet"], [f]


def case_scenario(s: Seeds, d: Path, rng: random.Random) -> tuple[list[str], list[Path]]:
    f = d / "scenario.yaml"
    text = _yaml_mutant(s.files["scenario"], rng)
    f.write_text(text.replace("package://besdrake_models/", "package://besdrake_models/") if text else text)
    return ["simulate", "--scenario", str(f), "--json"], [f]


def case_lab(s: Seeds, d: Path, rng: random.Random) -> tuple[list[str], list[Path]]:
    f = d / "lab.yaml"
    f.write_text(_yaml_mutant(s.files["lab"], rng))
    plan = d / "throw.plan.json"
    shutil.copy(s.files["plan"], plan)
    return ["lab", "run", "--lab", str(f), "--plans", str(plan), "--out", str(d / "log"), "--quiet"], [f, plan]


def case_config(s: Seeds, d: Path, rng: random.Random) -> tuple[list[str], list[Path]]:
    f = d / "config.yaml"
    f.write_text(_yaml_mutant(s.files["config"], rng))
    # Only the configuration is exercised (loading, validation, the run folder): the unknown stage ends it.
    return ["learn", "--config", str(f), "--out", str(d / "run"), "--stage", "no_such_stage", "--json"], [f]


def case_plugin(s: Seeds, d: Path, rng: random.Random) -> tuple[list[str], list[Path]]:
    name = f"fuzz_drag_{d.name}"
    text = PLUGIN.replace("EFFECT_NAME", name)
    if rng.random() < 0.5:
        old, new = rng.choice(PLUGIN_EDITS)
        text = text.replace(old, new)
    else:
        text = _mutate_text(text, rng)
    plugin = d / "plugin.py"
    plugin.write_text(text)
    lab = d / "lab.yaml"
    lab.write_text(f"name: fuzz_lab\nscenario: nominal\nplugins: [{plugin}]\neffects:\n  {name}: {{cd: 0.2}}\nseed: 0\n")
    plan = d / "throw.plan.json"
    shutil.copy(s.files["plan"], plan)
    return ["lab", "run", "--lab", str(lab), "--plans", str(plan), "--out", str(d / "log"), "--quiet"], [plugin, lab, plan]


def case_robot(s: Seeds, d: Path, rng: random.Random) -> tuple[list[str], list[Path]]:
    """A mutated robot file: ``simulate --robot`` (mostly) or ``learn --robot``'s configuration check."""
    from besdrake.sim.scenario import MODELS_DIR

    name = rng.choice(ROBOTS)
    f = d / "robot.yaml"
    f.write_text(_yaml_mutant(s.files[f"robot_{name}"], rng))
    models = [p for p in (MODELS_DIR / name).glob("*.urdf")]
    if rng.random() < 0.75:
        return ["simulate", "--robot", str(f), "--json"], [f, *models]
    return ["learn", "--quick", "--robot", str(f), "--out", str(d / "run"), "--stage", "no_such_stage", "--json"], [f, *models]


FORMATS: dict[str, Callable[[Seeds, Path, random.Random], tuple[list[str], list[Path]]]] = {
    "tsv": case_tsv,
    "c3d": case_c3d,
    "plan_json": case_plan,
    "scenario_yaml": case_scenario,
    "lab_yaml": case_lab,
    "config_yaml": case_config,
    "plugin": case_plugin,
    "demonstrations": case_demonstrations,
    "robot_yaml": case_robot,
}


# ---------------------------------------------------------------------------------------- running


@dataclass
class CaseResult:
    fmt: str
    argv: list[str]
    rc: int | None
    outcome: str  # ok | error | traceback | internal | bad_error_lines
    modified: list[str]
    detail: str


def _digest(p: Path) -> str | None:
    return hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else None


def run_case(fmt: str, seeds: Seeds, folder: Path, seed: int) -> CaseResult:
    """Make one mutated input of ``fmt`` in ``folder``, run the CLI in-process, classify the result."""
    import traceback

    from besdrake.cli import main
    from besdrake.sim.effects import list_effects, unregister_effect
    from besdrake import plugins

    rng = random.Random(f"{fmt}:{seed}")
    folder.mkdir(parents=True, exist_ok=True)
    argv, inputs = FORMATS[fmt](seeds, folder, rng)
    before = {p: _digest(p) for p in inputs}
    effects = set(list_effects())
    loaded = set(plugins._LOADED)
    out, err = io.StringIO(), io.StringIO()
    rc, outcome, detail = None, "ok", ""
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            rc = main(argv)
    except SystemExit as e:  # argparse (exit 2 with a usage line) -- not expected for file contents
        rc = e.code if isinstance(e.code, int) else 2
    except BaseException as e:  # noqa: BLE001 - this is what the fuzzer looks for
        if isinstance(e, KeyboardInterrupt):
            raise
        outcome, detail = "traceback", "".join(traceback.format_exception(type(e), e, e.__traceback__))[-2000:]
    finally:
        for name in set(list_effects()) - effects:
            unregister_effect(name)
        for path in set(plugins._LOADED) - loaded:  # the case's plugin file is deleted with its folder:
            plugins._LOADED.pop(path)  # executors made later must not load it into their workers
    lines = [ln for ln in err.getvalue().splitlines() if ln.startswith("besdrake: error:")]
    if outcome == "ok":
        if any("internal error" in ln for ln in lines):
            outcome, detail = "internal", lines[0]
        elif "Traceback (most recent call last)" in err.getvalue():
            outcome, detail = "traceback", err.getvalue()[-2000:]
        elif rc == 2 and len(lines) == 1 and "'no_such_stage'" in lines[0]:
            outcome = "ok"  # config_yaml: the configuration was accepted, the unknown stage ends the run
        elif rc == 2:
            outcome = "error" if len(lines) == 1 else "bad_error_lines"
            detail = lines[0] if lines else err.getvalue()[-300:]
        elif rc not in (0, 1):
            outcome, detail = "bad_error_lines", f"exit {rc}: {err.getvalue()[-300:]}"
    modified = [str(p) for p, h in before.items() if _digest(p) != h]
    return CaseResult(fmt, argv, rc, outcome, modified, detail)


def fuzz(per_format: int, formats: list[str] | None = None, seed0: int = 0, keep: Path | None = None) -> dict[str, Any]:
    """Run ``per_format`` cases of each format; JSON-ready counts and the failing cases."""
    import logging

    logging.getLogger("drake").setLevel(logging.WARNING)
    formats = formats or list(FORMATS)
    root = Path(tempfile.mkdtemp(prefix="besdrake-fuzz-"))
    t0 = time.perf_counter()
    try:
        seeds = make_seeds(root / "seeds")
        per: dict[str, dict[str, int]] = {}
        failures = []
        for fmt in formats:
            counts = per.setdefault(fmt, {"cases": 0, "ok": 0, "error": 0, "tracebacks": 0, "bad_error_lines": 0, "modified_inputs": 0})
            for k in range(per_format):
                folder = root / "cases" / f"{fmt}_{k}"
                res = run_case(fmt, seeds, folder, seed0 + k)
                counts["cases"] += 1
                counts[{"internal": "tracebacks", "traceback": "tracebacks"}.get(res.outcome, res.outcome)] += 1
                counts["modified_inputs"] += bool(res.modified)
                if res.outcome in ("traceback", "internal", "bad_error_lines") or res.modified:
                    failures.append({"format": fmt, "seed": seed0 + k, "argv": res.argv, "outcome": res.outcome,
                                     "modified": res.modified, "detail": res.detail})
                    if keep is not None:
                        shutil.copytree(folder, keep / folder.name, dirs_exist_ok=True)
                shutil.rmtree(folder, ignore_errors=True)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    total = {k: sum(c[k] for c in per.values()) for k in ("cases", "ok", "error", "tracebacks", "bad_error_lines", "modified_inputs")}
    return {"total": total, "per_format": per, "seconds": round(time.perf_counter() - t0, 1), "failures": failures}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--per-format", type=int, default=300, help="cases per format (default 300: 2,700 in all)")
    parser.add_argument("--formats", nargs="+", choices=list(FORMATS), default=None)
    parser.add_argument("--seed", type=int, default=0, help="first case seed")
    parser.add_argument("--keep", type=Path, default=None, help="copy the folders of failing cases here")
    parser.add_argument("--json", action="store_true", help="print only the JSON (default: JSON too)")
    args = parser.parse_args(argv)
    if args.keep:
        args.keep.mkdir(parents=True, exist_ok=True)
    res = fuzz(args.per_format, args.formats, args.seed, args.keep)
    print(json.dumps(res | {"failures": res["failures"][:20]}, indent=None if args.json else 1))
    return 0 if res["total"]["tracebacks"] == 0 and res["total"]["modified_inputs"] == 0 and res["total"]["bad_error_lines"] == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
