"""``besdrake imitate RECORDING``: demonstrated throws -> COMPI motion plans (one JSON per throw)."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

COMMAND = ("imitate",)
HELP = "imitate the throws of a demonstration as COMPI motion plans (sync frame, IK, scaling, DMP)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "recording",
        help="a Qualisys TSV / C3D file, or synthetic:SUBJECT[:EXPERIMENT] for the built-in synthetic demonstrator",
    )
    parser.add_argument("--out", type=Path, default=Path("runs/imitate"), help="folder for plans, DMPs, figures and summary.json")
    parser.add_argument(
        "--segments",
        choices=("auto", "given"),
        default="auto",
        help="auto: vMCI + 1-NN find the throws (default); given: use the *_manually_segmented.json beside the file "
        "(or the synthetic ground truth)",
    )
    parser.add_argument("--classifier", type=Path, default=None, help="classifier JSON ('besdrake eval classification --save-classifier')")
    parser.add_argument("--scenario", default="nominal", help="scenario to simulate the plans in (name or YAML path)")
    parser.add_argument("--no-sim", action="store_true", help="do not simulate the plans")
    parser.add_argument("--no-figures", action="store_true", help="do not write a PNG per throw")
    parser.add_argument("--max-throws", type=int, default=None, help="imitate at most this many throws per recording")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")


def run(args: argparse.Namespace) -> int:
    from besdrake._io import write_json

    t_start = time.perf_counter()
    demos, classifier, mapping, rollout = _inputs(args)
    recordings = _imitate_all(args, demos, classifier, mapping, rollout)
    summary = _summary(args, recordings, time.perf_counter() - t_start)
    write_json(args.out / "summary.json", summary)
    if args.json:
        print(json.dumps(summary, default=float))
    else:
        _print_summary(summary, recordings, args.out)
    return 0


def _inputs(args: argparse.Namespace):
    """The recordings, the classifier (``--classifier``, else None), the embodiment mapping of the scenario's robot and
    the rollout (None with ``--no-sim``); a bad input is a UserError."""
    from besdrake.cli import UserError
    from besdrake.embodiment import EmbodimentMapping
    from besdrake.mocap.recording import MocapFormatError
    from besdrake.sim.scenario import ScenarioError, load_scenario
    from besdrake.tasks.throwing.imitation import load_demonstration

    try:
        demos = load_demonstration(args.recording)
    except (FileNotFoundError, ValueError, MocapFormatError) as err:
        raise UserError(str(err)) from None
    classifier = None
    if args.classifier is not None:
        from besdrake.segmentation.classification import SegmentClassifier

        try:
            classifier = SegmentClassifier.from_json(json.loads(args.classifier.read_text()))
        except (OSError, ValueError) as err:
            raise UserError(f"classifier {args.classifier}: {err}") from None
    try:
        mapping = EmbodimentMapping(load_scenario(args.scenario).robot)
    except ScenarioError as err:
        raise UserError(str(err)) from None
    rollout = None
    if not args.no_sim:
        from besdrake.sim import Rollout

        rollout = Rollout(args.scenario)
    return demos, classifier, mapping, rollout


def _imitate_all(args: argparse.Namespace, demos, classifier, mapping, rollout) -> list[dict]:
    """One entry per recording: its imitated throws' reports, or the preprocessing error."""
    from besdrake.cli import UserError
    from besdrake.mocap.preprocess import PreprocessError
    from besdrake.tasks.throwing.imitation import find_throws, imitate_recording, prepare, reports_to_json

    recordings = []
    for name, rec, segments in demos:
        entry: dict = {"name": name}
        try:
            pre = prepare(rec)
        except PreprocessError as err:
            entry["error"] = f"preprocessing: {err}"
            recordings.append(entry)
            continue
        if args.segments == "given" and segments is None:
            raise UserError(f"{name}: --segments given but no segmentation file lies beside the recording")
        if args.segments == "auto" and classifier is None:
            from besdrake.tasks.throwing.imitation import default_classifier

            classifier = default_classifier()
        throws = find_throws(pre, classifier, segments if args.segments == "given" else None)
        if args.max_throws is not None:
            throws = throws[: args.max_throws]
        reports = imitate_recording(
            name, pre, throws, out_dir=args.out, simulate=not args.no_sim, figures=not args.no_figures,
            mapping=mapping, rollout=rollout,
        )
        entry["throws"] = reports_to_json(reports)
        recordings.append(entry)
    return recordings


def _summary(args: argparse.Namespace, recordings: list[dict], wall_s: float) -> dict:
    """``summary.json``: counts, the median imitation time, the largest IK residuals, the median landing distance."""
    throws = [t for r in recordings for t in r.get("throws", [])]
    times = [t["timings_s"]["total"] for t in throws if "timings_s" in t]
    landed = [t["simulation"]["touchdown_m"] for t in throws if t.get("simulation") and t["simulation"].get("touchdown_m")]
    return {
        "source": args.recording,
        "segments": args.segments,
        "out": str(args.out),
        "n_throws": len(throws),
        "n_executable": sum(1 for t in throws if t["executable"]),
        "n_failed": sum(1 for t in throws if t["error"]),
        "median_imitation_time_s": float(sorted(times)[len(times) // 2]) if times else None,
        "max_ik_position_residual_m": max((t["ik_max_position_residual_m"] for t in throws if "ik_max_position_residual_m" in t), default=None),
        "max_ik_angle_residual_deg": max((t["ik_max_angle_residual_deg"] for t in throws if "ik_max_angle_residual_deg" in t), default=None),
        "median_landing_distance_from_base_m": (
            float(sorted((x * x + y * y) ** 0.5 for x, y in landed)[len(landed) // 2]) if landed else None
        ),
        "wall_time_s": wall_s,
        "recordings": recordings,
    }


def _print_summary(summary: dict, recordings: list[dict], out) -> None:
    print(f"{summary['n_executable']}/{summary['n_throws']} throws imitated as executable plans "
          f"(median {summary['median_imitation_time_s'] or 0:.2f} s each); summary: {out / 'summary.json'}")
    for r in recordings:
        for t in r.get("throws", []):
            sim = t.get("simulation") or {}
            state = "ok" if t["executable"] else (t["error"] or "; ".join(t.get("problems", [])))
            print(f"  {r['name']} throw {t['index']} frames {t['start_frame']}-{t['end_frame']}: {state}; "
                  f"T={t.get('execution_time_s', float('nan')):.2f} s; sim: {', '.join(sim.get('flags', [])) or 'ok'} "
                  f"landing {sim.get('touchdown_m')}")
