"""The throwing task's first learn stages: 1. ``label`` (automatic marker labeling, gap filling), 2. ``segment``
(vMCI segmentation and 1-NN classification: the throw segments), 3. ``imitate`` (embodiment mapping and DMP imitation:
one plan of the robot per throw)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from besdrake._io import save_figure as _save_figure, write_text as _atomic_write_text
from besdrake._io import write_json
from besdrake.pipeline.learn import Context


def _synthetic(cfg: dict[str, Any]):
    from besdrake.tasks.throwing.demonstrator import SyntheticDemonstrator

    return SyntheticDemonstrator(int(cfg["demonstrations"]["seed"]))


def stage_label(ctx: Context, out: Path) -> dict[str, Any]:
    """Label unnamed marker trajectories (synthetic: the unlabelled variant) and fill gaps."""
    from besdrake.mocap.labeling import MarkerLabeler, labeling_accuracy
    from besdrake.mocap.qualisys import read_recording, write_tsv

    demo_cfg = ctx.config["demonstrations"]
    records = []
    if demo_cfg["source"] == "synthetic":
        demo = _synthetic(ctx.config)
        for s in demo_cfg["subjects"]:
            subject = demo.subject(int(s))
            first = subject.experiment(int(demo_cfg["experiments"][0]))
            ref_path = ctx.config["labeling"]["reference"]
            if ref_path:
                reference = read_recording(ref_path)
            else:  # a person labels the first 5 s once: the paper's "initial pose"
                reference = first.recording.crop(int(first.recording.frames[0]), int(first.recording.frames[0] + 5 * first.recording.frequency))
            labeler = MarkerLabeler().fit(reference)
            for e in demo_cfg["experiments"]:
                exp = subject.experiment(int(e))
                name = f"synthetic_s{s}_e{e}"
                if demo_cfg["unlabeled"]:
                    unlabeled, truth = subject.unlabeled_experiment(int(e), exp)
                    t0 = time.process_time()
                    result = labeler.predict(unlabeled)
                    cpu = time.process_time() - t0
                    acc = labeling_accuracy(result.slot_labels, truth)
                    rec = result.recording
                    records.append({"name": name, "cpu_s": cpu, "correct_share": acc["correct_share"],
                                    "gaps_flagged": result.summary()["gaps_flagged"]})
                else:
                    rec = exp.recording
                    records.append({"name": name, "cpu_s": 0.0, "correct_share": None})
                write_tsv(rec, out / f"{name}.tsv")
                from besdrake.mocap.segments_io import write_segmentation

                write_segmentation(exp.segments, out / f"{name}_manually_segmented.json")
    else:
        folder = Path(demo_cfg["source"])
        files = sorted([*folder.glob("*.tsv"), *folder.glob("*.c3d")])
        if not files:
            raise FileNotFoundError(f"no .tsv or .c3d recording in {folder}")
        ctx.run.record_inputs({f.name: f for f in files})
        for f in files:  # user recordings are expected to carry marker names already
            rec = read_recording(f)
            write_tsv(rec, out / f"{f.stem}.tsv")
            seg = f.with_name(f.stem + "_manually_segmented.json")
            if seg.is_file():
                _atomic_write_text(out / seg.name, seg.read_text())
            records.append({"name": f.stem, "cpu_s": 0.0, "correct_share": None})
    shares = [r["correct_share"] for r in records if r["correct_share"] is not None]
    return {
        "recordings": records,
        "median_cpu_s_per_experiment": float(np.median([r["cpu_s"] for r in records])),
        "min_correct_share": min(shares) if shares else None,
    }


def _training_classifier(ctx: Context):
    from besdrake.segmentation.classification import SegmentClassifier, extract_segment
    from besdrake.segmentation.evaluation import labelled_recordings, labelled_segments, pre_index
    from besdrake.tasks.throwing.imitation import prepare

    cfg = ctx.config["classifier"]
    if cfg.get("training_folder"):
        segments, labels = labelled_segments(labelled_recordings(cfg["training_folder"]))
        return SegmentClassifier(markers=("hand",)).fit(segments, labels), len(labels)
    demo = _synthetic(ctx.config)
    segments, labels = [], []
    for s in cfg["training_subjects"]:
        for e in cfg["training_experiments"]:
            exp = demo.subject(int(s)).experiment(int(e))
            pre = prepare(exp.recording)
            for seg in exp.segments:
                try:
                    a, b = pre_index(pre.frames, seg.start_frame), pre_index(pre.frames, seg.end_frame)
                except IndexError:
                    continue  # a segment in a cropped-away edge
                segments.append(extract_segment(pre, a, b, seg.label))
                labels.append(seg.label)
    return SegmentClassifier(markers=("hand",)).fit(segments, labels), len(labels)


def stage_segment(ctx: Context, out: Path) -> dict[str, Any]:
    """vMCI borders and 1-NN labels; throws written as segmentations; scored against manual borders."""
    from besdrake.mocap.qualisys import read_recording
    from besdrake.mocap.segments_io import Segment, read_segmentation, write_segmentation
    from besdrake.tasks.throwing.imitation import prepare
    from besdrake.segmentation import VMCI, ZeroVelocitySegmenter
    from besdrake.segmentation.classification import extract_segment
    from besdrake.segmentation.evaluation import manual_borders, score_borders

    label_dir = ctx.run.root / "01_label"
    t0 = time.perf_counter()
    classifier, n_train = _training_classifier(ctx)
    train_s = time.perf_counter() - t0
    method = ctx.config["segmentation"]["method"]
    results = []
    for tsv in sorted(label_dir.glob("*.tsv")):
        pre = prepare(read_recording(tsv))
        t1 = time.process_time()
        seg = (VMCI() if method == "vmci" else ZeroVelocitySegmenter()).fit(pre)
        seg_cpu = time.process_time() - t1
        t2 = time.process_time()
        found = []
        for a, b in seg.segments_:
            label = str(classifier.predict([extract_segment(pre, a, b)])[0])
            found.append(Segment(int(pre.frames[a]), int(pre.frames[b]), label))
        cls_cpu = time.process_time() - t2
        write_segmentation(found, out / f"{tsv.stem}_segments.json")
        if not results:  # one figure: the first recording's hand speed with the borders
            _plot_segmentation(pre, found, read_segmentation(tsv.with_name(tsv.stem + "_manually_segmented.json"))
                               if tsv.with_name(tsv.stem + "_manually_segmented.json").is_file() else None, out / f"{tsv.stem}_segments.png")
        entry = {"name": tsv.stem, "segments": len(found), "throws": sum(s.label == "throw" for s in found),
                 "segmentation_cpu_s": seg_cpu, "classification_cpu_s": cls_cpu, "duration_s": float(pre.time[-1] - pre.time[0])}
        manual = tsv.with_name(tsv.stem + "_manually_segmented.json")
        if manual.is_file():
            truth = read_segmentation(manual)
            true_b = manual_borders(truth, int(pre.frames[0]), int(pre.frames[-1]), pre.frequency)
            pred_b = np.array([s.start_frame for s in found[1:]])
            entry["border_f1_0.2s"] = score_borders(pred_b, true_b, pre.frequency, 0.2).f1
            true_throws = [s for s in truth if s.label == "throw"]
            hit = sum(any(abs(f.start_frame - t.start_frame) <= 0.2 * pre.frequency and f.label == "throw" for f in found) for t in true_throws)
            entry["throws_demonstrated"] = len(true_throws)
            entry["throws_found"] = hit
        results.append(entry)
    return {
        "classifier_training_segments": n_train,
        "classifier_training_s": train_s,
        "method": method,
        "recordings": results,
        "throws": sum(r["throws"] for r in results),
        "real_time_factor": sum(r["duration_s"] for r in results) / max(sum(r["segmentation_cpu_s"] for r in results), 1e-9),
    }


def _plot_segmentation(pre, found, manual, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    speed = np.linalg.norm(pre.hand_velocity_back, axis=1)
    fig, ax = plt.subplots(figsize=(12, 3.5))
    ax.plot(pre.time, speed, "k-", lw=0.8, label="hand speed")
    t_of = dict(zip(pre.frames.tolist(), pre.time.tolist()))
    colors = {"throw": "tab:red", "strike_out": "tab:orange", "swing_out": "tab:blue", "idle": "tab:grey"}
    for seg in found:
        t0, t1 = t_of.get(seg.start_frame), t_of.get(seg.end_frame)
        if t0 is not None and t1 is not None:
            ax.axvspan(t0, t1, color=colors.get(seg.label, "tab:green"), alpha=0.25, lw=0)
            ax.axvline(t0, color="tab:red", lw=0.6)
    for seg in manual or []:
        t0 = t_of.get(seg.start_frame)
        if t0 is not None:
            ax.axvline(t0, color="k", ls=":", lw=0.8)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("m/s")
    ax.set_title("vMCI borders (red lines), 1-NN labels (shading: throw red, strike_out orange, swing_out blue, idle grey), manual borders (dotted)")
    fig.tight_layout()
    _save_figure(fig, path, dpi=80)
    plt.close(fig)


def stage_imitate(ctx: Context, out: Path) -> dict[str, Any]:
    """Embodiment mapping and DMP imitation of every throw found; simulated in the designed scenario. The throws are
    spread over the configured workers (same results as one after the other); figures of the first ``figures``."""
    from besdrake.tasks.throwing.imitation import reports_to_json
    from besdrake.tasks.throwing.imitation_pool import imitate_throws

    jobs = _imitation_jobs(ctx)
    figures = ctx.config["imitation"].get("figures")
    for k, job in enumerate(jobs):
        job.figure = figures is None or k < int(figures)
    workers = 1 if ctx.config.get("ray_address") else int(ctx.config["workers"])
    throws_out = reports_to_json(imitate_throws(jobs, ctx.config["scenario"], out_dir=out, workers=workers))
    for job, t in zip(jobs, throws_out):
        t.setdefault("name", job.name)  # a throw that could not be imitated has no summary
    target = np.asarray(ctx.config["refinement"]["target"], dtype=float)
    for t in throws_out:
        sim = t.get("simulation") or {}
        td = sim.get("touchdown_m")
        t["target_distance_m"] = float(np.linalg.norm(np.asarray(td) - target)) if td else None
    write_json(out / "throws.json", throws_out)
    cpu = [t["timings_s"]["total"] for t in throws_out if "timings_s" in t]
    dists = [t["target_distance_m"] for t in throws_out if t["target_distance_m"] is not None]
    return {
        "throws": len(throws_out),
        "executable": sum(bool(t["executable"]) for t in throws_out),
        "median_time_per_throw_s": float(np.median(cpu)) if cpu else None,
        "median_target_distance_m": float(np.median(dists)) if dists else None,
        "min_target_distance_m": float(min(dists)) if dists else None,
    }


def _imitation_jobs(ctx: Context) -> list:
    """The throw segments of the segmentation stage, recording by recording, at most ``imitation.max_throws``."""
    from besdrake.mocap.qualisys import read_recording
    from besdrake.mocap.segments_io import read_segmentation
    from besdrake.tasks.throwing.imitation import prepare
    from besdrake.tasks.throwing.imitation_pool import ThrowJob

    max_throws = ctx.config["imitation"]["max_throws"]
    jobs: list[ThrowJob] = []
    for seg_file in sorted((ctx.run.root / "02_segment").glob("*_segments.json")):
        if max_throws is not None and len(jobs) >= int(max_throws):
            break
        name = seg_file.name[: -len("_segments.json")]
        throws = [(s.start_frame, s.end_frame) for s in read_segmentation(seg_file) if s.label == "throw"]
        if max_throws is not None:
            throws = throws[: max(0, int(max_throws) - len(jobs))]
        if throws:
            pre = prepare(read_recording(ctx.run.root / "01_label" / f"{name}.tsv"))
            jobs += [ThrowJob(f"{name}_throw{i}", i, pre, f0, f1) for i, (f0, f1) in enumerate(throws)]
    return jobs
