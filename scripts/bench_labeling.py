"""Benchmark: automatic marker labelling of synthetic throwing experiments (prints JSON).

For each subject, the labeller is fitted on experiment 1 (labelled) and labels experiments 2..N
delivered as unnamed trajectories (ghost markers, identities shuffled per gap or per frame).
Figures: share of correctly labelled samples against the generator's ground truth and CPU
seconds per experiment (8 throws; ``time.process_time`` of ``predict``, one process, one core).
Paper (Table 1): automatic marker labelling took 4:58 min per experiment.
Also printed: the same with a reference cut to its first 5 s (one throw), and a check on the
real pick-and-place recordings (identities removed, ghosts added; fit on run 1 of a subject).

Usage: python scripts/bench_labeling.py [--subjects 10] [--experiments 3] [--seed 0] [--shuffle gap|frame]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from besdrake.mocap.labeling import MarkerLabeler, labeling_accuracy
from besdrake.tasks.throwing.demonstrator import SyntheticDemonstrator, make_unlabeled

PAPER_SECONDS_PER_EXPERIMENT = 4 * 60 + 58


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--subjects", type=int, default=10)
    ap.add_argument("--experiments", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--shuffle", choices=("gap", "frame"), default="gap")
    args = ap.parse_args()
    demo = SyntheticDemonstrator(args.seed)
    totals = {"samples": 0, "correct": 0, "marker_samples": 0, "marker_correct": 0, "ghost_samples": 0, "ghost_rejected": 0}
    seconds, per_exp = [], []
    wall0 = time.perf_counter()
    for i in range(args.subjects):
        subj = demo.subject(i)
        labeler = MarkerLabeler().fit(subj.experiment(0).recording)
        for j in range(1, args.experiments):
            exp = subj.experiment(j)
            un, truth = subj.unlabeled_experiment(j, exp, args.shuffle)  # with long occlusions and ghosts
            t0 = time.process_time()
            res = labeler.predict(un)
            seconds.append(time.process_time() - t0)
            acc = labeling_accuracy(res.slot_labels, truth)
            per_exp.append({"subject": i + 1, "experiment": j + 1, "frames": un.n_frames, "correct_share": round(acc["correct_share"], 5),
                            "seconds": round(seconds[-1], 3), "gaps_flagged": sum(not g.filled for g in res.gaps)})
            totals["samples"] += acc["samples"]
            totals["correct"] += round(acc["correct_share"] * acc["samples"])
            totals["marker_samples"] += acc["marker_samples"]
            totals["marker_correct"] += round(acc["marker_correct_share"] * acc["marker_samples"])
            totals["ghost_samples"] += acc["ghost_samples"]
            totals["ghost_rejected"] += round(acc["ghost_rejected_share"] * acc["ghost_samples"])
    med = float(np.median(seconds))
    out = {
        "benchmark": "marker labelling, synthetic throws (fit on experiment 1, label the others)",
        "shuffle": args.shuffle,
        "experiments_labelled": len(seconds),
        "correct_share": round(totals["correct"] / totals["samples"], 5),
        "marker_correct_share": round(totals["marker_correct"] / totals["marker_samples"], 5),
        "ghost_rejected_share": round(totals["ghost_rejected"] / max(totals["ghost_samples"], 1), 5),
        "worst_experiment_correct_share": min(e["correct_share"] for e in per_exp),
        "cpu_seconds_per_experiment_median": round(med, 3),
        "cpu_seconds_per_experiment_max": round(float(np.max(seconds)), 3),
        "target_seconds_per_experiment": 10.0,
        "target_correct_share": 0.99,
        "paper_seconds_per_experiment": PAPER_SECONDS_PER_EXPERIMENT,
        "speedup_vs_paper": round(PAPER_SECONDS_PER_EXPERIMENT / med, 1),
        "wall_seconds_total_including_generation": round(time.perf_counter() - wall0, 2),
        "per_experiment": per_exp,
    }
    out["reference_first_5_s_only"] = short_reference_check(demo, args.subjects, args.experiments, 5.0)
    out["real_pick_and_place"] = real_data_check()
    print(json.dumps(out, indent=1))


def short_reference_check(demo: SyntheticDemonstrator, n_subjects: int, n_experiments: int, seconds: float) -> dict:
    """The same labelling with a reference cut to its first ``seconds`` (about one throw)."""
    correct = total = 0.0
    worst = 1.0
    for i in range(n_subjects):
        subj = demo.subject(i)
        ref = subj.experiment(0).recording
        ref = ref.crop(int(ref.frames[0]), int(ref.frames[0] + seconds * ref.frequency) - 1)
        labeler = MarkerLabeler().fit(ref)
        for j in range(1, n_experiments):
            un, truth = subj.unlabeled_experiment(j)
            acc = labeling_accuracy(labeler.predict(un).slot_labels, truth)
            correct += acc["correct_share"] * acc["samples"]
            total += acc["samples"]
            worst = min(worst, acc["correct_share"])
    return {"reference_seconds": seconds, "correct_share": round(correct / total, 5), "worst_experiment_correct_share": round(worst, 5)}


def real_data_check() -> dict | str:
    """The real recordings of ../shared/data/pick_and_place (13 markers, 60 Hz, no gaps): fit on
    run 1 of a subject, label its other runs with identities removed and ghosts added."""
    from pathlib import Path

    from besdrake.mocap.qualisys import read_tsv

    folder = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "pick_and_place"
    if not folder.is_dir():
        return "shared data not found"
    runs = []
    per_marker: dict[str, list[float]] = {}
    for subject in (1, 2):
        ref_path = folder / f"subject{subject}_run1.tsv"
        if not ref_path.exists():
            continue
        ref = read_tsv(ref_path)
        labeler = MarkerLabeler().fit(ref)
        for path in sorted(folder.glob(f"subject{subject}_run*.tsv")):
            if path == ref_path:
                continue
            rec = read_tsv(path).select(ref.marker_names)
            un, truth = make_unlabeled(rec, np.random.default_rng(len(runs)), 0.3)
            res = labeler.predict(un)
            acc = labeling_accuracy(res.slot_labels, truth, ref.marker_names)
            runs.append({"file": path.name, "correct_share": round(acc["correct_share"], 4), "seconds": round(res.seconds, 3)})
            for name, v in acc["per_marker"].items():
                per_marker.setdefault(name, []).append(v)
    return {
        "runs": runs,
        "median_correct_share": float(np.median([r["correct_share"] for r in runs])),
        "per_marker_mean_share": {k: round(float(np.mean(v)), 4) for k, v in per_marker.items()},
        "note": "Box back/Box left sit on a moved box (two markers, symmetric): swapped or rejected in some runs; "
                "subject 1 runs 6-9 have the elbow marker re-attached (3 cm shorter upper arm than run 1)",
    }


if __name__ == "__main__":
    main()
