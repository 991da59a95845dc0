#!/usr/bin/env python3
"""Benchmark ``besdrake learn`` itself on several demonstrators' subjects: wall and CPU time, stage times, the
refinement's runs and the template's figures per subject; prints a table (stderr) and JSON figures (stdout, ``--json``).

Each subject runs the whole command line a user runs (``python3 -m besdrake learn --out OUT/learn_sS --set
demonstrations.subjects=[S]`` plus ``--set`` overrides), one after the other, as a child process whose wall-clock and
CPU time (its own and its workers') are measured here and written beside its run folder (``OUT/learn_sS.time.json``).
A subject whose run folder is complete and has that file is not run again (a killed benchmark resumes; a run folder
the benchmark did not time is run again in a fresh folder). Subject 0 is learn's default demonstration.

Targets (issue 27): ``besdrake learn`` on the defaults <= 4 min on 2 quiet cores; the template after 80 episodes <= 5
cm in simulation and <= 7 cm in the lab (mean over the 16 test contexts) on bases refined from at least 5 subjects;
every refinement run reaches 0.1 m. Printed: per subject and the median / mean over the subjects. Seconds depend on
the machine: before and after the subjects the benchmark times ``besdrake bench rollout``'s reference throw on one core
(:func:`besdrake.tasks.throwing.bench.reference_rollout_ms`) and prints the wall times in those reference rollouts too,
figures that compare between machines (the CPU model is recorded).

    python3 scripts/bench_learn.py --subjects 0 1 2 3 4 --out /tmp/bench_learn --json /tmp/bench_learn.json
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's besdrake, not another worktree's installed copy


def _stage_folders() -> list[str]:
    """The run folder's stage folders in order, as :class:`besdrake.pipeline.run.RunFolder` names them."""
    from besdrake.tasks.throwing.learn import STAGES

    return [f"{i:02d}_{name}" for i, (name, _) in enumerate(STAGES, 1)]


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _run_subject(subject: int, out: Path, overrides: list[str], workers: int, quick: bool = False) -> dict:
    """Run learn for ``subject`` into ``out / learn_sS`` (unless done and timed) and return its measured times."""
    run = out / f"learn_s{subject}"
    timing = out / f"learn_s{subject}.time.json"
    if timing.is_file() and (run / _stage_folders()[-1] / "stage.json").is_file():
        return json.loads(timing.read_text())
    if run.exists():  # not timed by this benchmark, or killed: a fresh folder (the old one is kept aside)
        run.rename(out / f"learn_s{subject}.untimed.{int(time.time())}")
    cmd = [sys.executable, "-m", "besdrake", "learn", "--out", str(run), "--workers", str(workers),
           "--set", f"demonstrations.subjects=[{subject}]"] + (["--quick"] if quick else [])
    for text in overrides:
        cmd += ["--set", text]
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    cpu0, t0 = _children_cpu(), time.perf_counter()
    with open(out / f"learn_s{subject}.log", "w") as log:
        proc = subprocess.run(cmd, cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
    measured = {"wall_s": time.perf_counter() - t0, "cpu_s": _children_cpu() - cpu0, "returncode": proc.returncode, "command": cmd}
    if proc.returncode == 0:
        timing.write_text(json.dumps(measured, indent=1))
    return measured


def _stage(run: Path, folder: str) -> dict:
    f = run / folder / "stage.json"
    return json.loads(f.read_text()) if f.is_file() else {}


def _row(subject: int, run: Path, measured: dict) -> dict:
    """The figures of one subject's run folder."""
    stages = {folder[3:]: _stage(run, folder) for folder in _stage_folders()}
    refine = stages["refine"].get("summary", {})
    template = stages["template"].get("summary", {})
    reach = template.get("reach_refinement") or {}
    executors = {name: (s.get("summary", {}).get("executor") or {}).get("rollouts") for name, s in stages.items()}
    return {
        "subject": subject, "run": str(run), "wall_s": measured.get("wall_s"), "cpu_s": measured.get("cpu_s"),
        "returncode": measured.get("returncode"),
        "stage_s": {name: s.get("seconds") for name, s in stages.items()},
        "stage_rollouts": {k: v for k, v in executors.items() if v is not None},
        "refine_runs": [{"episodes": r.get("n_episodes"), "best_distance_m": r.get("best_distance_within_limits_m"),
                         "episodes_to_0.1_m": r.get("episodes_to_success"), "stop_reason": r.get("stop_reason")} for r in refine.get("runs", [])],
        "reach_refinement": {k: reach.get(k) for k in ("start_distance_m", "best_distance_m", "episodes", "other_runs", "other_family",
                                                       "other_families", "floor_m", "kept_from")},
        "template_sim_cm": None if template.get("sim_mean_distance_m") is None else 100.0 * template["sim_mean_distance_m"],
        "template_lab_cm": None if template.get("lab_mean_distance_m") is None else 100.0 * template["lab_mean_distance_m"],
    }


def _table(rows: list[dict]) -> str:
    from besdrake.pipeline.learn import fmt_time as _fmt

    lines = ["subject  wall        cpu s  refine      template    refine runs (episodes, best m)          template sim / lab cm"]
    for r in rows:
        runs = ", ".join(f"{x['episodes']} {x['best_distance_m']:.3f}" for x in r["refine_runs"] if x["best_distance_m"] is not None)
        sim, lab = r["template_sim_cm"], r["template_lab_cm"]
        lines.append(f"{r['subject']:>7}  {_fmt(r['wall_s']):>10}  {r['cpu_s'] or 0:>5.0f}  {_fmt(r['stage_s'].get('refine')):>10}  "
                     f"{_fmt(r['stage_s'].get('template')):>10}  {runs:<40} {sim if sim is None else round(sim, 2)} / {lab if lab is None else round(lab, 2)}")
    return "\n".join(lines)


def summarize(rows: list[dict]) -> dict:
    """Medians and means over the subjects, and the issue-27 targets they are judged against."""
    ok = [r for r in rows if r["returncode"] == 0]
    walls = [r["wall_s"] for r in ok]
    sims = [r["template_sim_cm"] for r in ok if r["template_sim_cm"] is not None]
    labs = [r["template_lab_cm"] for r in ok if r["template_lab_cm"] is not None]
    runs = [x for r in ok for x in r["refine_runs"]]
    default = next((r for r in ok if r["subject"] == 0), None)
    return {
        "subjects": [r["subject"] for r in rows], "failed": [r["subject"] for r in rows if r["returncode"] != 0],
        "default_subject_wall_s": None if default is None else default["wall_s"],
        "median_wall_s": float(np.median(walls)) if walls else None, "max_wall_s": max(walls) if walls else None,
        "mean_template_sim_cm": float(np.mean(sims)) if sims else None, "mean_template_lab_cm": float(np.mean(labs)) if labs else None,
        "max_template_lab_cm": max(labs) if labs else None,
        "refine_runs_reaching_0.1_m": sum(x["best_distance_m"] is not None and x["best_distance_m"] <= 0.1 for x in runs), "refine_runs": len(runs),
        "targets": {"default_wall_s": 240.0, "template_sim_cm": 5.0, "template_lab_cm": 7.0, "refine_run_m": 0.1},
    }


def _in_reference(summary: dict, reference: dict) -> dict:
    """The wall times in reference rollouts (the mean of the references before and after the subjects): figures that
    compare between machines, where the seconds do not."""
    ms = float(np.mean([reference["before"]["ms_per_rollout"], reference["after"]["ms_per_rollout"]]))
    per = {k: None if summary[k] is None else summary[k] * 1000.0 / ms for k in ("default_subject_wall_s", "median_wall_s")}
    return {"ms_per_rollout": ms, "default_wall_rollouts": per["default_subject_wall_s"], "median_wall_rollouts": per["median_wall_s"],
            "target_default_wall_rollouts": summary["targets"]["default_wall_s"] * 1000.0 / ms}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--subjects", type=int, nargs="+", default=[0, 1, 2, 3, 4], help="demonstrator subjects, one learn run each")
    parser.add_argument("--out", required=True, help="folder of the run folders (rerun the same command to resume)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="learn setting for every subject (repeatable)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--quick", action="store_true", help="learn's smoke profile (a check of the benchmark, not its figures)")
    parser.add_argument("--json", default=None, help="also write the figures here")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from besdrake.tasks.throwing.bench import reference_rollout_ms

    reference = {"before": reference_rollout_ms()}
    rows = []
    for s in args.subjects:
        print(f"subject {s} ...", file=sys.stderr, flush=True)
        measured = _run_subject(s, out, args.set, args.workers, args.quick)
        rows.append(_row(s, out / f"learn_s{s}", measured))
        print(_table(rows[-1:]).splitlines()[1], file=sys.stderr, flush=True)
        if measured.get("returncode"):
            print(f"    learn failed (exit {measured['returncode']}): see {out / f'learn_s{s}.log'}", file=sys.stderr, flush=True)
    reference["after"] = reference_rollout_ms()
    summary = summarize(rows)
    summary["reference"] = _in_reference(summary, reference)
    note = f"{os.cpu_count()} CPU cores ({reference['before']['cpu_model']}); wall times need quiet cores"
    result = {"settings": args.set, "workers": args.workers, "quick": args.quick, "rows": rows, "summary": summary,
              "reference": reference, "machine_note": note}
    print(_table(rows), file=sys.stderr, flush=True)
    ref, before, after = summary["reference"], reference["before"]["ms_per_rollout"], reference["after"]["ms_per_rollout"]
    print(f"reference rollout (bench rollout's default throw, one core): {ref['ms_per_rollout']:.2f} ms (before {before:.2f}, "
          f"after {after:.2f}); default subject's wall = {ref['default_wall_rollouts'] or float('nan'):,.0f} reference rollouts, "
          f"median {ref['median_wall_rollouts'] or float('nan'):,.0f}", file=sys.stderr, flush=True)
    text = json.dumps(result, indent=1, default=str)
    if args.json:
        Path(args.json).write_text(text)
    print(text)
    return 0 if not result["summary"]["failed"] else 1


if __name__ == "__main__":
    sys.exit(main())
