#!/usr/bin/env python3
"""Benchmark: grasp demonstrations from the real pick-and-place recordings (prints JSON).

Per subject: recordings, approach/transport pairs found, pairs with a usable grasp, the
per-file problems and rejected pairs with their reasons (counted), CPU seconds per file, the pairs that match the annotators' pair (the
found transport starts within ``--tolerance`` s of the manual one), and the spread of the
task-frame figures over the demonstrations (table place, box yaw, grasp timing).

Classifiers: ``shipped`` (``classifier.npz``: trained on all recordings of subjects 1 and 2,
so it has seen the files it labels) and ``cross_subject`` (trained on the other subject's
manual segments: the figure for recordings no classifier has seen), both with and without
joining over-split pieces. ``classifier_accuracy`` is the 1-NN's accuracy on the other subject's
manual segments (``evaluate_classifier``).

Usage: python3 scripts/bench_pnp_demonstrations.py [--data DIR] [--tolerance 0.3] [--quick]
(``--quick``: the shipped classifier with joining only). ``unnamed_shipped_join``: the same from
unnamed trajectories (each subject's later runs, labelled by a labeller fitted on its first run).
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

import numpy as np

from besdrake.mocap.segments_io import read_segmentation, segmentation_path
from besdrake.segmentation.classification import SegmentClassifier
from besdrake.segmentation.evaluation import evaluate_classifier, labelled_recordings
from besdrake.tasks.pick_and_place.classifier import load_classifier, train_classifier
from besdrake.tasks.pick_and_place.demonstrations import APPROACH, TRANSPORT, extract_demonstrations

DEFAULT_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "pick_and_place"


def manual_transport_start(path: Path) -> int | None:
    seg = segmentation_path(path)
    if not seg.exists():
        return None
    starts = [s.start_frame for s in read_segmentation(seg) if s.label == TRANSPORT]
    return starts[0] if starts else None


def run_subject(files: list[Path], classifier, join: bool, tolerance_s: float, labeler=None,
                manual_of=lambda f: f) -> dict:
    found = usable = matched = 0
    reasons: Counter = Counter()
    seconds, demos, per_file = [], [], []
    for f in files:
        res = extract_demonstrations(f, classifier=classifier, join=join, labeler=labeler)
        seconds.append(res.seconds)
        found += res.pairs_found
        usable += len(res.demonstrations)
        reasons.update(r.reason for r in res.rejected)
        reasons.update(res.problems)
        manual = manual_transport_start(manual_of(f))
        for d in res.demonstrations:
            if manual is not None and abs(d.transport_frames[0] - manual) <= tolerance_s * 60:
                matched += 1
        demos.extend(res.demonstrations)
        per_file.append({"file": f.name, "pairs": res.pairs_found, "usable": len(res.demonstrations),
                         "problems": res.problems, "rejected": [r.reason for r in res.rejected]})
    return {"recordings": len(files), "pairs_found": found, "usable": usable,
            "usable_matching_manual_pair": matched, "problems_and_rejections": dict(reasons),
            "cpu_s_per_file_median": round(float(np.median(seconds)), 3),
            "cpu_s_per_file_max": round(float(np.max(seconds)), 3),
            "task_frame": spread(demos), "per_file": per_file}


def unnamed(files: list[Path], classifier, tolerance_s: float) -> dict:
    """The subject's runs after the first as unnamed trajectories (identities shuffled per gap, ghost
    markers added), named by a labeller fitted on the first run, then the shipped pipeline."""
    import tempfile

    from besdrake.mocap.labeling import MarkerLabeler
    from besdrake.mocap.qualisys import read_tsv, write_tsv
    from besdrake.tasks.throwing.demonstrator import make_unlabeled

    labeler = MarkerLabeler().fit(read_tsv(files[0]))
    with tempfile.TemporaryDirectory() as tmp:
        copies = {}
        for k, f in enumerate(files[1:]):
            rec, _ = make_unlabeled(read_tsv(f), np.random.default_rng(k), 0.3)
            copies[Path(tmp) / f.name] = f
            write_tsv(rec, Path(tmp) / f.name)
        res = run_subject(list(copies), classifier, True, tolerance_s, labeler, manual_of=lambda c: copies[c])
    res["reference"] = files[0].name
    return res


def spread(demos) -> dict:
    """Median and range of the task-frame figures over demonstrations."""
    if not demos:
        return {}

    def stat(values) -> dict:
        v = np.asarray(values, dtype=float)
        return {"median": round(float(np.median(v)), 4), "min": round(float(v.min()), 4), "max": round(float(v.max()), 4)}

    return {
        "table_distance_m": stat([d.table_box_position[0] for d in demos]),
        "table_height_m": stat([d.table_box_position[2] for d in demos]),
        "shelf_yaw_rad_mod_pi": stat(np.unwrap([d.shelf_box_yaw for d in demos], period=np.pi)),
        "table_yaw_rad_mod_pi": stat(np.unwrap([d.table_box_yaw for d in demos], period=np.pi)),
        "shelf_place_world_m": {a: stat([d.frame_origin[i] for d in demos]) for i, a in enumerate("xyz")},
        "hand_start_task_m": {a: stat([d.hand_position[0, i] for d in demos]) for i, a in enumerate("xyz")},
        "hand_at_close_task_m": {a: stat([np.interp(d.close_time, d.t, d.hand_position[:, i]) for d in demos])
                                 for i, a in enumerate("xyz")},
        "close_before_lift_s": stat([d.lift_time - d.close_time for d in demos]),
        "open_after_place_s": stat([d.open_time - d.place_time for d in demos]),
        "hold_aperture_m": stat([d.hold_aperture for d in demos]),
        "box_marker_span_m": stat([d.box_marker_span for d in demos]),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--tolerance", type=float, default=0.3, help="seconds between found and manual transport start")
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    files = sorted(args.data.glob("*.tsv"))
    subjects = sorted({f.name.split("_")[0] for f in files})
    by = {s: [f for f in files if f.name.startswith(s + "_")] for s in subjects}
    shipped = load_classifier()
    out: dict = {"data": str(args.data), "definitions": {"pair": f"{APPROACH} run, then {TRANSPORT} run (idle between)",
                                                         "matching": f"transport start within {args.tolerance} s of the manual one"}}
    recs = labelled_recordings(args.data)
    for s in subjects:
        other = [o for o in subjects if o != s]
        entry = {"shipped_join": run_subject(by[s], shipped, True, args.tolerance)}
        if other and not args.quick:
            cross, _ = train_classifier(args.data, other)
            entry["shipped_no_join"] = run_subject(by[s], shipped, False, args.tolerance)
            entry["cross_subject_join"] = run_subject(by[s], cross, True, args.tolerance)
            entry["cross_subject_no_join"] = run_subject(by[s], cross, False, args.tolerance)
            test = [r for r in recs if r.path.name.startswith(s + "_")]
            train = [r for r in recs if not r.path.name.startswith(s + "_")]
            res = evaluate_classifier(SegmentClassifier(), train, test)
            entry["classifier_accuracy_trained_on_" + "+".join(other)] = {
                k: res[k] for k in ("accuracy", "per_class_accuracy", "n_train", "n_test", "confusions")}
        if not args.quick:
            entry["unnamed_shipped_join"] = unnamed(by[s], shipped, args.tolerance)
        out[s] = entry
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
