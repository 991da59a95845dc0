"""The throwing task's ``besdrake learn`` stages (:func:`besdrake.pipeline.learn.learn` runs them; configuration:
``learn.yaml`` beside this module), from demonstrations to a template pool (paper Table 1 and Figure 1):

 1. ``label``      automatic marker labeling (unnamed trajectories -> named markers), gap filling
 2. ``segment``    vMCI segmentation and 1-NN classification: the throw segments
 3. ``imitate``    embodiment mapping and DMP imitation: one plan of the robot per throw
 4. ``refine``     policy search in simulation (CMA-ES on the 49 DMP parameters)
 5. ``transfer``   Transferability Approach with the designed simulation and the lab
 6. ``diagnose``   what the simulation gets wrong, its cause, a refined scenario
 7. ``transfer_refined``  Transferability Approach again, with the refined simulation
 8. ``template``   behaviour template learning (BO-CPS) over the target position
 9. ``pool``       the template pool
10. ``report``     report.md with figures and meshcat replays
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from besdrake._io import save_figure as _save_figure, write_text as _atomic_write_text
from besdrake._io import write_json
from besdrake.pipeline.learn import Context, fmt_time as _fmt_time, learn_scenario
from besdrake.pipeline.learn import stage_executor as _executor


#: Paper Table 1, per experiment of 8 throws: (stage, time in s, automated, required knowledge).
PAPER_TABLE_1: dict[str, tuple[str, float | None, str, str]] = {
    "label": ("Automatic marker labeling", 4 * 60 + 58, "yes", "Neighboring markers, initial pose"),
    "segment": ("Behavior segmentation + movement classification", 44 + 2, "yes", "labelled training throws (classification)"),
    "imitate": ("Imitation learning", 4 * 60 + 20, "yes", "Robot description"),
    "refine": ("Policy search", 10 * 60, "yes", "Reward function, simulation"),
    "transfer": ("Transferability approach", 75 * 60, "(yes)", "Reward function, simulation"),
    "diagnose": ("Simulation refinement (paper: grid search on height and release angle)", None, "yes", "effect registry"),
    "transfer_refined": ("Transferability approach after refinement", None, "(yes)", "Reward function, refined simulation"),
    "template": ("Behavior template learning (paper: 80 episodes on the robot)", None, "yes", "Reward function, context space"),
    "pool": ("Behavior template pool", None, "yes", "-"),
}


# --------------------------------------------------------------------------------------------
# 1. labeling
# --------------------------------------------------------------------------------------------
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


# --------------------------------------------------------------------------------------------
# 2. segmentation and classification
# --------------------------------------------------------------------------------------------
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


# --------------------------------------------------------------------------------------------
# 3. imitation
# --------------------------------------------------------------------------------------------
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


# --------------------------------------------------------------------------------------------
# 4. refinement in simulation
# --------------------------------------------------------------------------------------------
def _refine_from(ctx: Context, dmps: list, scenario: str, out: Path, budget: int, tag: str, scouting: bool = True,
                 target: tuple[float, float] | None = None, plans: int | None = None,
                 reward_settings: dict[str, Any] | None = None, sigma0: float | None = None, start_group: int = 0,
                 follow_through: float | None = None, robust: bool = True) -> dict[str, Any]:
    """CMA-ES from the best of ``dmps`` (the paper uses all available plans) in ``scenario``. The default search's scouts
    (short first attempts from the best throws) run only with ``scouting`` and where they take at most half of
    ``budget``: a re-refinement from throws refined already goes straight to CMA-ES from the best of them.
    ``target`` and ``plans`` (runs): the refinement section's unless given; ``reward_settings``: more settings of the
    task's reward (e.g. the template reach's ``radial``); ``sigma0``: CMA-ES's initial step (normalised units; None: the
    refinement's default); ``start_group``: the first run starts from the throws ranked ``4 * start_group`` on (later
    runs from the next groups where ``refinement.run_starts`` is diverse); ``follow_through``: s after each start throw's
    release from which its plans are slowed where they break a limit, as a template plays them (None: off); ``robust``:
    the refinement's robust check (``refinement.robust_sd``) where it is on (False: every throw scored as thrown)."""
    from besdrake.search.refinement import (DEFAULT_SCOUTS, DEFAULT_SIGMA0, SUCCESS_DISTANCE, RefinementProblem, plot_learning_curves, rank_starts,
                                            refine, scouting_episodes)
    from besdrake.search.refinement.run import stops_at
    from besdrake.sim.scheduler import run_concurrently
    from besdrake.task import DEFAULT_TASK, get_task
    from besdrake.tasks.throwing.template_base import follow_through_phase

    cfg = ctx.config["refinement"]
    task = str(ctx.config.get("task") or DEFAULT_TASK)
    reward = get_task(task).reward(target=tuple(cfg["target"] if target is None else target), **(reward_settings or {}))
    n_runs = int(cfg["plans"] if plans is None else plans)
    robot = ctx.robot(scenario)
    settings = refinement_settings(ctx.config)
    check = _robust_check(task, scenario, settings) if robust else None
    with _executor(ctx, scenario) as executor:
        phases = [follow_through_phase(d, executor, robot, follow_through) for d in dmps]
        problems = [RefinementProblem(robot, d, reward, task=task, robust=check, follow_through=ph) for d, ph in zip(dmps, phases)]
        ranking = rank_starts(problems, executor)
        index, start = ranking[0]
        problem = problems[index]
        records = dict(ranking)
        if settings["stop_on_success"] and stops_at(start, settings["stop_distance"] or SUCCESS_DISTANCE):
            return _keep_start(ctx, problem, robot, index, start, out, tag)
        scouts = DEFAULT_SCOUTS if scouting and 2 * scouting_episodes(int(cfg["population"])) <= int(budget) else 0
        diverse = bool(scouts) and settings["run_starts"] == "diverse"
        run_starts = [_run_starts(problems, ranking, start_group + (k if diverse else 0)) for k in range(n_runs)]

        def run_job(k: int):
            """CMA-ES run ``k`` (its own seed, start throws and resumable folder) on the shared executor ``ex``."""
            def job(ex):
                i, starts = run_starts[k]
                ctx.progress(f"{tag}: CMA-ES run {k + 1}/{n_runs} from throw {i} ({records[i].distance:.2f} m from the target)")
                return refine(problems[i], ex, n_episodes=int(budget), seed=int(cfg["seed"]) + k, out_dir=out / f"run{k}",
                              sigma0=DEFAULT_SIGMA0 if sigma0 is None else sigma0,
                              popsize=int(cfg["population"]), stop_on_success=settings["stop_on_success"],
                              stop_distance=settings["stop_distance"], starts=starts, scouts=scouts, stall=settings["stall"],
                              switch_distance=settings["switch_distance"] if scouts else None)
            return job

        jobs = [run_job(k) for k in range(n_runs)]
        if settings["stop_on_success"] and settings["runs_in_turn"]:
            results = _runs_in_turn(jobs, executor, settings["turn_distance"] or settings["stop_distance"] or SUCCESS_DISTANCE)
        else:  # independent runs: their generations share the pool, one wider batch per round (same results)
            results = run_concurrently(executor, jobs)
    runs = _save_refined([problems[run_starts[k][0]] for k in range(len(results))], robot, results, out)
    for k, run in enumerate(runs):
        run["start_throw"] = int(run_starts[k][0])
    plot_learning_curves(results, out / "learning_curve.png")
    # The best run is judged by throws within every joint limit: a closer throw that breaks a limit is no plan.
    best = min(runs, key=lambda r: r["best_distance_within_limits_m"] if r["best_distance_within_limits_m"] is not None else np.inf)
    return {
        "start_throw": int(index),
        "start_distance_m": start.distance,
        "runs": runs,
        "success_runs": sum(bool(r["success"]) for r in runs),
        "median_episodes_to_success": float(np.median([r["episodes_to_success"] for r in runs if r["episodes_to_success"]])) if any(r["episodes_to_success"] for r in runs) else None,
        "best_distance_within_limits_m": best["best_distance_within_limits_m"],
        "best_dmp": best["dmp"],
    }


def _runs_in_turn(jobs: list, executor, turn_distance: float) -> list:
    """The CMA-ES runs one after the other on ``executor``, up to the first that found a throw within
    ``turn_distance`` (its robust distance where checked): a later run only where every earlier one failed."""
    results = []
    for job in jobs:
        results.append(job(executor))
        if results[-1].reached(turn_distance):
            break
    return results


def _keep_start(ctx: Context, problem, robot, index: int, start, out: Path, tag: str) -> dict[str, Any]:
    """No CMA-ES run: the best start throw already lands within the stop distance (e.g. a re-refinement from a refined
    throw); it is kept as ``refined0`` (0 episodes)."""
    ctx.progress(f"{tag}: throw {index} lands {start.distance:.3f} m from the target already: kept, no CMA-ES run")
    out.mkdir(parents=True, exist_ok=True)
    _save_throw(problem.parameterization.from_vector(problem.theta(np.zeros(problem.n_params))), robot, out, 0)  # retimed, as evaluated
    run = {"success": True, "episodes_to_success": 0, "best_distance_m": start.distance, "best_distance_within_limits_m": start.distance,
           "best_touchdown_m": list(start.touchdown), "n_episodes": 0, "stop_reason": "start", "dmp": "refined0.dmp.json"}
    if np.isfinite(start.robust_distance):
        run["best_robust_distance_m"] = start.robust_distance
    return {"start_throw": int(index), "start_distance_m": start.distance, "runs": [run], "success_runs": 1,
            "median_episodes_to_success": 0.0, "best_distance_within_limits_m": start.distance, "best_dmp": run["dmp"]}


def _run_starts(problems: list, ranking: list, group: int) -> tuple[int, Any]:
    """:func:`~besdrake.search.refinement.run_start` over the throws of ``ranking`` that could be simulated."""
    from besdrake.search.refinement import run_start, simulated_order

    return run_start(problems, simulated_order(ranking), group)


def _save_refined(problems: list, robot, results: list, out: Path) -> list[dict[str, Any]]:
    """Each run's best throw (of ``problems[k]``, the run's problem) as ``refinedK.dmp.json`` and ``refinedK.plan.json``;
    the runs' summaries."""
    runs = []
    for k, (problem, result) in enumerate(zip(problems, results)):
        _save_throw(problem.parameterization.from_vector(result.best_theta), robot, out, k)
        runs.append(result.summary() | {"dmp": f"refined{k}.dmp.json"})
    return runs


def _save_throw(dmp, robot, out: Path, k: int) -> None:
    """A refined throw as ``refinedK.dmp.json`` and its motion plan (10 ms samples) as ``refinedK.plan.json``."""
    from besdrake.imitation import DMPParameterization

    dmp.save(out / f"refined{k}.dmp.json")
    DMPParameterization(dmp, robot.joint_names).motion_plan(DMPParameterization(dmp).to_vector(), dt=0.01).save(out / f"refined{k}.plan.json")


def refinement_settings(config: dict[str, Any]) -> dict[str, Any]:
    """The refinement section's stop and robustness settings, checked (:class:`~besdrake.pipeline.config.ConfigError`):
    ``stop_on_success``, ``runs_in_turn`` (the runs one after the other up to the first success), ``stop_distance`` (m;
    null: the success distance), ``turn_distance`` (m: with ``runs_in_turn`` a run follows only where every earlier one
    ended beyond it; null: the stop distance) and ``robust_sd`` (m per axis; 0: no robust check), ``robust_radius`` (m),
    ``robust_frontier`` (m; null or absent, as in a run folder of before: every throw within the radius checked, not only
    those that could become the run's best), ``stall`` (a
    :class:`~besdrake.search.refinement.StallRule` from ``stall_episodes`` / ``stall_tol`` / ``stall_after``; None where
    ``stall_episodes`` is null), ``switch_distance`` (m; a raced scout that stalls farther hands over to the next one;
    null: never)."""
    from besdrake.pipeline.config import ConfigError
    from besdrake.search.refinement import SUCCESS_DISTANCE, RefinementError
    from besdrake.search.refinement.optimizer import checked_switch_distance
    from besdrake.search.refinement.robust import ROBUST_RADIUS

    cfg = config["refinement"]
    try:
        stop = cfg.get("stop_distance")
        out = {"stop_on_success": bool(cfg.get("stop_on_success", True)), "stop_distance": None if stop is None else float(stop),
               "runs_in_turn": bool(cfg.get("runs_in_turn", False)), "run_starts": str(cfg.get("run_starts", "same")),
               "robust_sd": float(cfg.get("robust_sd", 0.0)), "robust_radius": float(cfg.get("robust_radius", ROBUST_RADIUS)),
               "robust_frontier": None if cfg.get("robust_frontier") is None else float(cfg["robust_frontier"])}
        out["switch_distance"] = checked_switch_distance(cfg.get("switch_distance"))
    except (TypeError, ValueError, RefinementError) as err:
        raise ConfigError(f"refinement: {err}") from None
    out["stall"] = _stall_rule(cfg)
    out["turn_distance"] = _turn_distance(cfg.get("turn_distance"))
    if out["stop_distance"] is not None and not (0 < out["stop_distance"] <= SUCCESS_DISTANCE):
        raise ConfigError(f"refinement: stop_distance must be within (0, {SUCCESS_DISTANCE}] m or null, got {stop!r}")
    if out["run_starts"] not in ("same", "diverse"):
        raise ConfigError(f"refinement: run_starts must be 'same' or 'diverse', got {out['run_starts']!r}")
    if not (0 <= out["robust_sd"] <= 0.005) or not (out["robust_radius"] > 0):
        raise ConfigError(f"refinement: robust_sd must be within 0..0.005 m and robust_radius > 0 m, "
                          f"got {out['robust_sd']!r}, {out['robust_radius']!r}")
    if out["robust_frontier"] is not None and not (0 < out["robust_frontier"] < out["robust_radius"]):
        raise ConfigError(f"refinement: robust_frontier must be within (0, robust_radius) m or null, got {out['robust_frontier']!r}")
    return out


def _turn_distance(value: Any) -> float | None:
    """``refinement.turn_distance`` checked: None, or a distance within (0, the success distance] m."""
    from besdrake.pipeline.config import ConfigError
    from besdrake.search.refinement import SUCCESS_DISTANCE

    try:
        turn = None if value is None else float(value)
    except (TypeError, ValueError):
        turn = float("nan")
    if turn is not None and not (0 < turn <= SUCCESS_DISTANCE):
        raise ConfigError(f"refinement: turn_distance must be within (0, {SUCCESS_DISTANCE}] m or null, got {value!r}")
    return turn


def _stall_rule(cfg: dict[str, Any]):
    """The refinement section's stall rule (None: ``stall_episodes`` null or absent)."""
    from besdrake.pipeline.config import ConfigError
    from besdrake.search.refinement import RefinementError, StallRule

    if cfg.get("stall_episodes") is None:
        return None
    try:
        return StallRule(int(cfg["stall_episodes"]), float(cfg.get("stall_tol", 0.01)), int(cfg.get("stall_after", 400)))
    except (TypeError, ValueError, RefinementError) as err:
        raise ConfigError(f"refinement: {err}") from None


def _robust_check(task: str, scenario: str, settings: dict[str, Any]):
    """The refinement's :class:`~besdrake.search.refinement.robust.RobustCheck` over the task's setup scatter in
    ``scenario`` (None with ``robust_sd`` 0)."""
    from besdrake.search.refinement.robust import RobustCheck
    from besdrake.sim.scenario import load_scenario
    from besdrake.task import get_task

    if settings["robust_sd"] <= 0:
        return None
    return RobustCheck.from_task(get_task(task), load_scenario(scenario), settings["robust_sd"], radius=settings["robust_radius"],
                                 frontier=settings.get("robust_frontier"))


def stage_refine(ctx: Context, out: Path) -> dict[str, Any]:
    return _refine_from(ctx, _imitated(ctx), ctx.config["scenario"], out, int(ctx.config["refinement"]["evaluations"]), "refine")


def _imitated(ctx: Context) -> list:
    """The imitation stage's DMPs (RuntimeError where it produced none)."""
    from besdrake.imitation import load_dmp

    files = sorted((ctx.run.root / "03_imitate").glob("*.dmp.json"))
    if not files:
        raise RuntimeError("no imitated throw to refine (the imitation stage produced no plan)")
    return [load_dmp(f) for f in files]


# --------------------------------------------------------------------------------------------
# 5. and 7. the Transferability Approach
# --------------------------------------------------------------------------------------------
def _lab(ctx: Context):
    from besdrake.transfer.lab import SafetyGate
    from besdrake.transfer.lab_config import open_lab, resolve_lab_path

    if "lab" not in ctx.cache:
        ctx.run.record_inputs({"lab": resolve_lab_path(ctx.config["lab"])})
        ctx.cache["lab"] = SafetyGate(open_lab(ctx.config["lab"]))
    return ctx.cache["lab"]


def _open_log(folder: Path, lab):
    from besdrake.transfer.log import LabLog

    return LabLog.open(folder) if (folder / "log.json").is_file() else LabLog.create(folder, lab.description())


def transfer_config(config: dict[str, Any]):
    """The Transferability Approach's settings of a learn configuration (checked before any stage runs);
    :class:`~besdrake.pipeline.config.ConfigError` names a bad value."""
    from besdrake.pipeline.config import ConfigError
    from besdrake.transfer.transferability import PLACEMENT_SD, TransferabilityConfig

    cfg = config["transfer"]
    try:
        return TransferabilityConfig(
            target=tuple(config["refinement"]["target"]), population=int(cfg["population"]),
            max_transfers=int(cfg["max_transfers"]), final_repetitions=int(cfg["final_repetitions"]),
            transfer_choice=str(cfg.get("transfer_choice", "likely")), placement_sd=float(cfg.get("placement_sd", PLACEMENT_SD)),
            futility_p=None if cfg.get("futility_p") is None else float(cfg["futility_p"]),
            futility_transfers=int(cfg.get("futility_transfers", 3)),
        )
    except (TypeError, ValueError) as err:
        raise ConfigError(f"transfer: {err}") from None


def diagnosis_design(config: dict[str, Any], limits=None) -> list:
    """The diagnosis experiment's plans of a learn configuration (checked before any stage runs): ``throws`` plans
    with ``repeats``, ``probes`` tilt probes and ``sideways`` sideways throws (joints 1, 4 and 6 moved, within the
    robot's joint ``limits``; default: those of :func:`learn_scenario`'s robot). :class:`~besdrake.pipeline.config.ConfigError`
    names a bad value."""
    from besdrake.diagnosis import diagnosis_plans
    from besdrake.pipeline.config import ConfigError

    cfg = config["diagnosis"]
    try:
        sideways = int(cfg.get("sideways", 0))
        if int(cfg.get("refine_top", 3)) < 1:
            raise ConfigError(f"diagnosis: refine_top must be an integer >= 1, got {cfg.get('refine_top')!r}")
        if sideways and limits is None:
            limits = learn_scenario(config).robot.limits
        return diagnosis_plans(n=int(cfg["throws"]), repeats=int(cfg["repeats"]), seed=int(config["transfer"]["seed"]), probes=int(cfg.get("probes", 0)),
                               sideways=sideways, limits=limits)
    except (TypeError, ValueError) as err:
        if isinstance(err, ConfigError):
            raise
        raise ConfigError(f"diagnosis: {err}") from None


def _seed_files(folder: Path, best: str | None) -> list[Path]:
    """The refined throws in ``folder``, the refinement's best (file name ``best``) first: the search's template."""
    files = sorted(folder.glob("refined*.dmp.json"))
    return sorted(files, key=lambda f: f.name != best)


def _transfer(ctx: Context, seed_files: list[Path], scenario: str, out: Path) -> dict[str, Any]:
    """The Transferability Approach from ``seed_files`` (best first): the seeds the first one's parameterization
    represents (a throw refined from another imitated throw has another goal velocity and is left out)."""
    from besdrake.imitation import load_dmp, shared_parameterization
    from besdrake.search.refinement import ParameterScaling
    from besdrake.transfer.transferability import TransferabilityApproach

    cfg = ctx.config["transfer"]
    robot = ctx.robot(scenario)
    loaded = [load_dmp(f) for f in seed_files]
    param, kept = shared_parameterization(loaded, robot.joint_names)
    left_out = [f.name for i, f in enumerate(seed_files) if i not in kept]
    if left_out:
        ctx.progress(f"transfer seeds: {seed_files[0].name}" + "".join(f", not {n} (refined from another imitated throw)" for n in left_out))
    dmps = [loaded[i] for i in kept]
    scaling = ParameterScaling.for_dmp(dmps[0], robot.position_limits)
    lab = _lab(ctx)
    log = _open_log(out / "lab_log", lab)
    config = transfer_config(ctx.config)
    with _executor(ctx, scenario) as executor:
        search = TransferabilityApproach(
            lambda theta: param.motion_plan(theta, dt=0.01), np.array([param.to_vector(d) for d in dmps]),
            scaling.scale, scaling.bounds, executor, lab, np.random.default_rng(int(cfg["seed"])), config,
            log=log, out_dir=out, progress=ctx.progress,
        )
        result = search.run()
    summary = result.summary() | {"scenario": scenario, "seeds": [seed_files[i].name for i in kept], "seeds_left_out": left_out}
    if result.best_theta is not None:
        best = param.from_vector(result.best_theta)
        best.save(out / "best.dmp.json")
        param.motion_plan(result.best_theta, dt=0.01).save(out / "best.plan.json")
    write_json(out / "transfers.json", [t.__dict__ for t in result.transfers])
    return summary


def stage_transfer(ctx: Context, out: Path) -> dict[str, Any]:
    refine_dir = ctx.run.root / "04_refine"
    best = ctx.run.done(4, "refine")["summary"].get("best_dmp")
    return _transfer(ctx, _seed_files(refine_dir, best), ctx.config["scenario"], out)


# --------------------------------------------------------------------------------------------
# 6. diagnosis
# --------------------------------------------------------------------------------------------
def stage_diagnose(ctx: Context, out: Path) -> dict[str, Any]:
    """Run the diagnosis experiment in the lab, diagnose its log, write the refined scenario."""
    from besdrake.diagnosis import diagnose
    from besdrake.diagnosis.report import write_report
    from besdrake.transfer.log import run_plans

    lab = _lab(ctx)
    log = _open_log(out / "lab_log", lab)
    cfg = ctx.config["diagnosis"]
    plans = diagnosis_design(ctx.config, limits=ctx.robot().limits)
    run_plans(lab, plans, log)
    t0 = time.perf_counter()
    with _executor(ctx, ctx.config["scenario"]) as executor:
        diag = diagnose(log.measurements(), scenario=ctx.config["scenario"], pairs=bool(cfg["pairs"]), executor=executor,
                        refine_top=int(cfg.get("refine_top", 3)))
    seconds = time.perf_counter() - t0
    paths = write_report(diag, out / "report")
    summary = diag.summary()
    rel = {k: (None if paths[k] is None else str(Path(paths[k]).relative_to(ctx.run.root))) for k in ("scenario", "report")}
    return summary | {"diagnosis_s": seconds, "lab_trials": len(log), "refined_scenario": rel["scenario"], "report": rel["report"]}


def _refined_scenario(ctx: Context) -> str:
    """The diagnosis's refined scenario (stored relative to the run folder, so a copied or moved run folder
    resumes with its own file), or the configured scenario."""
    done = ctx.run.done(6, "diagnose")
    if not ctx.config["diagnosis"]["enabled"] or done is None or not done["summary"].get("refined_scenario"):
        return ctx.config["scenario"]
    path = Path(done["summary"]["refined_scenario"])
    return str(path if path.is_absolute() else ctx.run.root / path)


def stage_transfer_refined(ctx: Context, out: Path) -> dict[str, Any]:
    """Re-refine the throws in the refined simulation, then the Transferability Approach again."""
    from besdrake.imitation import load_dmp

    scenario = _refined_scenario(ctx)
    seeds = [load_dmp(f) for f in sorted((ctx.run.root / "04_refine").glob("refined*.dmp.json"))]
    budget = max(int(ctx.config["refinement"]["evaluations"]) // 2, 20)
    refined = _refine_from(ctx, seeds, scenario, out / "refine", budget, "re-refine", scouting=False)
    summary = _transfer(ctx, _seed_files(out / "refine", refined.get("best_dmp")), scenario, out)
    return summary | {"re_refinement": refined}


# --------------------------------------------------------------------------------------------
# 8. behaviour template, 9. pool
# --------------------------------------------------------------------------------------------
def _best_throw(ctx: Context) -> Path:
    for candidate in (ctx.run.root / "07_transfer_refined" / "best.dmp.json", ctx.run.root / "05_transfer" / "best.dmp.json"):
        if candidate.is_file():
            return candidate
    return ctx.run.root / "04_refine" / ctx.run.done(4, "refine")["summary"]["best_dmp"]


#: What the template's reach refinement scores: "point" the touchdown's distance to ``reach_target``, "range" its
#: distance from the robot against the target's (any direction: the template's joint-1 goal turns the throw).
REACH_OBJECTIVES = ("point", "range")


def template_reach_settings(config: dict[str, Any]) -> dict[str, Any]:
    """The templates section's reach settings, checked (:class:`~besdrake.pipeline.config.ConfigError`): the reach
    refinement's ``target`` (m, or None: off), ``evaluations`` (episodes), ``objective`` (:data:`REACH_OBJECTIVES`) and
    ``sigma`` (its CMA-ES's initial step), ``robust`` (whether it scores throws by the refinement's robust check),
    ``extend_probes`` (the template's probes beyond its slowest time), ``slowest`` (the template's slowest execution
    time, x its base's) and ``robust_sd`` (m: the setup scatter the template's episodes are rewarded over; 0: none)."""
    from besdrake.pipeline.config import ConfigError
    from besdrake.search.templates import EXTEND_PROBES, SCALE_SLOWEST
    from besdrake.search.refinement import DEFAULT_SIGMA0

    cfg = config["templates"]
    target, budget, objective = cfg.get("reach_target"), cfg.get("reach_evaluations", 0), cfg.get("reach_objective", "point")
    try:
        target = None if target is None else tuple(float(v) for v in target)
        budget = int(budget)
        other = int(cfg.get("reach_other_evaluations", 0))
        other_runs = cfg.get("reach_other_runs", False)
        sigma = float(cfg.get("reach_sigma", DEFAULT_SIGMA0))
        extend = int(cfg.get("extend_probes", EXTEND_PROBES))
        slowest = float(cfg.get("slowest", SCALE_SLOWEST))
        follow = cfg.get("follow_through")
        follow = None if follow is None else float(follow)
        robust = cfg.get("reach_robust", True)
        robust_sd = float(cfg.get("robust_sd", 0.0))
    except (TypeError, ValueError) as err:
        raise ConfigError(f"templates: reach_target must be [x, y] in m or null, reach_evaluations an integer and slowest "
                          f"a number ({err})") from None
    if target is not None and (len(target) != 2 or not np.isfinite(target).all()) or budget < 0:
        raise ConfigError(f"templates: reach_target must be two finite numbers (m) or null and reach_evaluations >= 0, "
                          f"got {cfg.get('reach_target')!r}, {cfg.get('reach_evaluations')!r}")
    if other < 0:
        raise ConfigError(f"templates: reach_other_evaluations must be >= 0, got {cfg.get('reach_other_evaluations')!r}")
    if not 0 <= extend <= 10:
        raise ConfigError(f"templates: extend_probes must be an integer within [0, 10], got {cfg.get('extend_probes')!r}")
    if not (np.isfinite(sigma) and 0.0 < sigma <= 5.0):
        raise ConfigError(f"templates: reach_sigma must be within (0, 5] (CMA-ES's initial step), got {cfg.get('reach_sigma')!r}")
    if objective not in REACH_OBJECTIVES:
        raise ConfigError(f"templates: reach_objective must be one of {REACH_OBJECTIVES}, got {objective!r}")
    if not (1.0 < slowest <= 10.0):
        raise ConfigError(f"templates: slowest must be within (1, 10] (x the base's execution time), got {cfg.get('slowest')!r}")
    if not (np.isfinite(robust_sd) and 0.0 <= robust_sd <= 0.05):
        raise ConfigError(f"templates: robust_sd must be within [0, 0.05] m (0: off), got {cfg.get('robust_sd')!r}")
    if not isinstance(robust, bool):
        raise ConfigError(f"templates: reach_robust must be true or false, got {robust!r}")
    if not isinstance(other_runs, bool):
        raise ConfigError(f"templates: reach_other_runs must be true or false, got {other_runs!r}")
    if follow is not None and not (np.isfinite(follow) and 0.0 <= follow <= 1.0):
        raise ConfigError(f"templates: follow_through must be a time within [0, 1] s after the release, or null, got {cfg.get('follow_through')!r}")
    return {"target": target if budget > 0 else None, "evaluations": budget, "slowest": slowest, "objective": objective,
            "sigma": sigma, "extend_probes": extend, "other_evaluations": other, "other_runs": other_runs,
            "follow_through": follow, "robust": robust, "robust_sd": robust_sd}


def _template_base(ctx: Context, scenario: str, out: Path) -> tuple[Path, dict[str, Any]]:
    """The template's base: the best refined throw, refined further towards ``templates.reach_target`` (issue 27).

    A throw refined to land at the refinement's target drives a joint at its speed limit, so a template cannot make it
    throw farther: contexts beyond its touchdown are missed by the shortfall, while a slower execution reaches the nearer
    ones. Refined towards the farthest context, the base covers the context range. The further-refined throw is kept
    only where the template's reach probes of both throws leave it the smaller floor (the test contexts' mean distance
    that no meta-parameters avoid, :func:`~besdrake.search.templates.reach_floor`): a throw family may not reach the
    target, and one that lands a little farther may turn less far (joint 1's limits). Where that refinement ends short
    of the goal (0.1 m), a second one from other imitated throws (ranked 5-8, ``templates.reach_other_evaluations``)
    looks in another throw family, and the floor rule picks among the three."""
    from besdrake.imitation import load_dmp
    from besdrake.search.templates import reach_floor
    from besdrake.tasks.throwing.template_base import follow_through_phase

    base_file = _best_throw(ctx)
    settings = template_reach_settings(ctx.config)
    if settings["target"] is None:
        return base_file, {}
    result = _reach_refinement(ctx, [load_dmp(base_file)], scenario, out, settings["evaluations"], settings, "template reach")
    record = {"target_m": list(settings["target"]), "objective": settings["objective"]} | _reach_summary(result)
    if result["runs"][0].get("stop_reason") == "start" or result["best_distance_within_limits_m"] is None:
        return base_file, record | {"kept": False}
    candidates, kinds = [base_file, out / result["best_dmp"]], ["refined throw", "reach refinement"]
    for name, run in _other_runs_reach(ctx, base_file, scenario, out, settings, result["best_distance_within_limits_m"]):
        record.setdefault("other_runs", []).append({"from": name} | {k: run[k] for k in ("start_distance_m", "best_distance_m", "episodes")})
        candidates.append(run["best_file"])
        kinds.append(f"reach refinement from {name}")
    other = _other_family(ctx, scenario, out / "other", settings, result["best_distance_within_limits_m"])
    if other is not None:
        record["other_family"] = {k: other[k] for k in ("start_distance_m", "best_distance_m", "episodes")}
        candidates.append(out / "other" / other["best_dmp"])
        kinds.append("other throws")
    with _executor(ctx, scenario) as executor:
        robot = ctx.robot(scenario)
        dmps = [load_dmp(f) for f in candidates]
        floors = [reach_floor(d, executor, robot, slowest=settings["slowest"],
                              follow_through=follow_through_phase(d, executor, robot, settings["follow_through"])) for d in dmps]
    pick = int(np.argmin(floors))
    record |= {"floor_m": floors, "kept": pick > 0, "kept_from": kinds[pick]}
    return candidates[pick], record


def _reach_refinement(ctx: Context, dmps: list, scenario: str, out: Path, budget: int, settings: dict[str, Any], tag: str,
                      start_group: int = 0) -> dict[str, Any]:
    """One CMA-ES run towards the template's reach target; from a later start group (other imitated throws) with scouts
    where the budget allows them, from the refined throw without; its throws played as the template will play them
    (``templates.follow_through``), scored robustly only with ``templates.reach_robust``."""
    return _refine_from(ctx, dmps, scenario, out, budget, tag, scouting=start_group > 0, target=settings["target"], plans=1,
                        reward_settings={"radial": True} if settings["objective"] == "range" else None, sigma0=settings["sigma"],
                        start_group=start_group, follow_through=settings["follow_through"], robust=settings["robust"])


def _other_run_throws(ctx: Context, base_file: Path, scenario: str) -> list[Path]:
    """The refinement runs' throws of another throw family than ``base_file`` (refined from another imitated throw: the
    base's search space does not represent them), in run order."""
    from besdrake.imitation import load_dmp, shared_parameterization

    files = sorted((ctx.run.root / "04_refine").glob("refined*.dmp.json"))
    if not files:
        return []
    _, kept = shared_parameterization([load_dmp(base_file)] + [load_dmp(f) for f in files], ctx.robot(scenario).joint_names)
    return [f for i, f in enumerate(files, start=1) if i not in kept]


def _other_runs_reach(ctx: Context, base_file: Path, scenario: str, out: Path, settings: dict[str, Any],
                      reached: float) -> list[tuple[str, dict[str, Any]]]:
    """Where the reach refinement ended ``reached`` m from its target, beyond the goal: one reach refinement (the same
    budget) from each of the refinement's other runs' throws of another family (``templates.reach_other_runs``). The
    refinement keeps the closest of its runs, but a throw family that lands on the refinement's target may reach no
    farther, while another run's lands a little off and reaches the far contexts (issue 27). Returns (throw file name,
    {start_distance_m, best_distance_m, episodes, best_file}) per run that ended within the joint limits."""
    from besdrake.imitation import load_dmp
    from besdrake.search.refinement import SUCCESS_DISTANCE

    if reached <= SUCCESS_DISTANCE or not settings["other_runs"]:
        return []
    found = []
    for f in _other_run_throws(ctx, base_file, scenario):
        name = f.name.split(".")[0]
        result = _reach_refinement(ctx, [load_dmp(f)], scenario, out / name, settings["evaluations"], settings,
                                   f"template reach (from {f.name})")
        if result["best_distance_within_limits_m"] is not None:
            found.append((f.name, _reach_summary(result) | {"best_file": out / name / result["best_dmp"]}))
    return found


def _reach_summary(result: dict[str, Any]) -> dict[str, Any]:
    """A reach refinement's start and best distance (m) and its episodes, as the template stage records them."""
    return {"start_distance_m": result["start_distance_m"], "best_distance_m": result["best_distance_within_limits_m"],
            "episodes": int(sum(r.get("n_episodes", 0) for r in result["runs"]))}


def _other_family(ctx: Context, scenario: str, out: Path, settings: dict[str, Any], reached: float) -> dict[str, Any] | None:
    """Where the reach refinement ended ``reached`` m from its target, beyond the goal: a reach refinement from the
    imitated throws ranked 5-8 (scouts from them: another throw family than the refined throw's); None where the first
    reached the goal or ``other_evaluations`` is 0."""
    from besdrake.search.refinement import SUCCESS_DISTANCE

    if reached <= SUCCESS_DISTANCE or settings["other_evaluations"] <= 0:
        return None
    result = _reach_refinement(ctx, _imitated(ctx), scenario, out, settings["other_evaluations"], settings,
                               "template reach (other throws)", start_group=1)
    return _reach_summary(result) | {"best_dmp": result["best_dmp"]}


def stage_template(ctx: Context, out: Path) -> dict[str, Any]:
    """BO-CPS over (execution time, joint-1 goal) in the refined simulation, from the refined throw refined further to
    reach the farthest context (:func:`_template_base`); tested in simulation and in the lab."""
    from besdrake.imitation import load_dmp
    from besdrake.search.templates import TEST_CONTEXTS, evaluate_template, train_template
    from besdrake.task import scenario_scatter
    from besdrake.tasks.throwing.template_base import follow_through_phase

    cfg = ctx.config["templates"]
    reach_settings = template_reach_settings(ctx.config)
    method = {"entropy_search": "es", "ucb": "ucb"}.get(cfg["acquisition"], cfg["acquisition"])
    scenario = _refined_scenario(ctx)
    base_file, reach = _template_base(ctx, scenario, out / "reach")
    with _executor(ctx, scenario) as executor:
        base = load_dmp(base_file)
        follow = follow_through_phase(base, executor, ctx.robot(scenario), reach_settings["follow_through"])
        training = train_template(
            base, executor, method=method, n_episodes=int(cfg["episodes"]), seed=int(cfg["seed"]),
            name="throw", out_dir=out / "training", slowest=reach_settings["slowest"], extend_probes=reach_settings["extend_probes"],
            follow_through=follow, scatter=scenario_scatter(executor.scenario, reach_settings["robust_sd"]),
            provenance={"base": str(base_file), "scenario": scenario, "lab": ctx.config["lab"], "demonstrations": ctx.config["demonstrations"]},
        )
        sim_eval = evaluate_template(training.template, executor)
    training.template.save(out)
    lab = _lab(ctx)
    log = _open_log(out / "lab_log", lab)
    from besdrake.transfer.log import run_plans

    run_plans(lab, [training.template.instantiate(s) for s in TEST_CONTEXTS], log)
    lab_td = np.array([m.touchdown if m.touchdown is not None else [np.nan, np.nan] for m in log.measurements()])
    lab_dist = np.linalg.norm(lab_td - TEST_CONTEXTS, axis=1)
    _plot_template(TEST_CONTEXTS, sim_eval.touchdowns, lab_td, out / "template_accuracy.png")
    prov = training.template.provenance
    return {
        "method": method,
        "episodes": int(cfg["episodes"]),
        "probe_rollouts": int(prov["n_probe_rollouts"]),
        "base": str(base_file),
        "reach_refinement": reach,
        "follow_through": follow,
        "scenario": scenario,
        "meta_bounds": training.template.meta_bounds.tolist(),
        "base_reach_m": _base_reach(prov.get("reach_probe")),
        "model_floor_mean_m": _model_floor(training.template),
        "sim_mean_distance_m": float(sim_eval.mean_distance),
        "sim_distances_m": [round(float(d), 5) for d in sim_eval.distances],  # per test context (TEST_CONTEXTS' order)
        "lab_mean_distance_m": float(np.nanmean(lab_dist)),
        "lab_not_measured": int(np.isnan(lab_dist).sum()),
        # what the lab adds to the simulation's touchdowns (its own scatter and what the refined scenario misses)
        "lab_about_sim_mean_m": _nanmean_or_none(np.linalg.norm(lab_td - sim_eval.touchdowns, axis=1)),
        "training_wall_time_s": training.wall_time,
    }


def _nanmean_or_none(x: np.ndarray) -> float | None:
    return float(np.nanmean(x)) if np.isfinite(x).any() else None


def _base_reach(probe: dict | None) -> list[float] | None:
    """Nearest and farthest touchdown (m) of the template's probes of its base within the joint limits."""
    if not probe:
        return None
    r = np.linalg.norm(np.array(probe["touchdowns"], dtype=float), axis=1)[np.array(probe["within_limits"], dtype=bool)]
    r = r[np.isfinite(r)]
    return [float(r.min()), float(r.max())] if r.size else None


def _model_floor(template) -> float | None:
    """Mean distance (m) over the test contexts that the probes' model says no meta-parameters in the box avoid."""
    from besdrake.search.template_reach import ReachProbe, model_floor
    from besdrake.search.templates import TEST_CONTEXTS

    probe = template.provenance.get("reach_probe")
    if not probe:
        return None
    return float(np.mean(model_floor(ReachProbe.from_dict(probe), template.meta_bounds, TEST_CONTEXTS)))


def _plot_template(contexts: np.ndarray, sim_td: np.ndarray, lab_td: np.ndarray, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 6))
    ax.plot(contexts[:, 1], contexts[:, 0], "k+", ms=12, label="test targets")
    ax.plot(sim_td[:, 1], sim_td[:, 0], "o", mfc="none", label="simulation (refined)")
    ax.plot(lab_td[:, 1], lab_td[:, 0], "x", label="lab")
    for c, t in zip(contexts, lab_td):
        ax.plot([c[1], t[1]], [c[0], t[0]], "-", lw=0.5, color="grey")
    ax.set_xlabel("y (lateral, m)")
    ax.set_ylabel("x (forward, m)")
    ax.set_aspect("equal")
    ax.legend(fontsize=8)
    ax.set_title("behaviour template on the 16 test contexts")
    fig.tight_layout()
    _save_figure(fig, path, dpi=90)
    plt.close(fig)


def stage_pool(ctx: Context, out: Path) -> dict[str, Any]:
    from besdrake.search.templates import BehaviorTemplate, TemplatePool

    template = BehaviorTemplate.load(next((ctx.run.root / "08_template").glob("*.template.json")))
    pool = TemplatePool(out)
    pool.add(template, overwrite=True)
    return {"pool": str(out), "templates": pool.names(), "instantiate": f"besdrake template instantiate --pool {out} --name {template.name} --context X Y"}


# --------------------------------------------------------------------------------------------
# 10. report
# --------------------------------------------------------------------------------------------
def stage_report(ctx: Context, out: Path) -> dict[str, Any]:
    """report.md: the paper's Table 1 with this run's times, every stage's figures, replays."""
    from besdrake.plan import MotionPlan
    from besdrake.sim.record import record_html

    root = ctx.run.root
    done = {name: ctx.run.done(i, name) for i, (name, _) in enumerate(STAGES[:-1], 1)}
    n_exp = max(1, len(done["label"]["summary"]["recordings"])) if done.get("label") else 1
    replays = []
    for stage, folder in (("transfer_refined", "07_transfer_refined"), ("transfer", "05_transfer")):
        plan_file = root / folder / "best.plan.json"
        if plan_file.is_file():
            scenario = _refined_scenario(ctx) if stage == "transfer_refined" else ctx.config["scenario"]
            html, _ = record_html(MotionPlan.load(plan_file), out / f"best_throw_{stage}.html", scenario=scenario, limits="flag", host=ctx.meshcat_host)
            replays.append(html.name)
    lines = [
        "# besdrake learn: report",
        "",
        f"Run folder `{root}`; configuration in `config.yaml`. Times are wall-clock on this machine; the paper's are per "
        f"experiment of 8 throws (this run: {n_exp} experiment(s)).",
        "",
        "## Table 1: each stage, its time, whether it ran without a person, what it needed",
        "",
        "| stage | this run | per experiment | paper (per experiment) | automated | required knowledge |",
        "|---|---|---|---|---|---|",
    ]
    per_experiment = {"label", "segment", "imitate"}
    for name, _ in STAGES[:-1]:
        rec = done.get(name)
        title, paper_s, automated, knowledge = PAPER_TABLE_1[name]
        seconds = rec["seconds"] if rec else None
        per = _fmt_time(seconds / n_exp) if (rec and name in per_experiment) else "-"
        lines.append(f"| {title} | {_fmt_time(seconds) if rec else 'not run'} | {per} | {_fmt_time(paper_s)} | {automated} | {knowledge} |")
    lines += ["", "Manual steps of the paper that a virtual lab needs no person for: attaching markers (0:55 min), motion capture "
              "(1:08 min), manual marker labeling (9:19 min), labelling the classifier's training set (50 min, done once).", ""]
    sections = {
        "label": ("Automatic marker labeling", "01_label"),
        "segment": ("Segmentation and classification", "02_segment"),
        "imitate": ("Imitation (embodiment mapping, DMP)", "03_imitate"),
        "refine": ("Policy search in simulation", "04_refine"),
        "transfer": ("Transferability Approach, designed simulation", "05_transfer"),
        "diagnose": ("Diagnosis: what the simulation gets wrong", "06_diagnose"),
        "transfer_refined": ("Transferability Approach, refined simulation", "07_transfer_refined"),
        "template": ("Behaviour template", "08_template"),
        "pool": ("Template pool", "09_pool"),
    }
    for name, (title, folder) in sections.items():
        rec = done.get(name)
        lines += [f"## {title}", ""]
        if rec is None:
            lines += ["Not run.", ""]
            continue
        summary = {k: v for k, v in rec["summary"].items() if not isinstance(v, (list, dict)) or k in ("gain",)}
        lines += ["| key | value |", "|---|---|"] + [f"| {k} | {_short(v)} |" for k, v in summary.items()] + [""]
        for png in sorted((root / folder).glob("*.png"))[:2] + sorted((root / folder).glob("*/*.png"))[:3]:
            lines.append(f"![{png.stem}]({png.relative_to(root).as_posix()})")
        lines.append("")
    lines += _workers_table(done)
    if replays:
        lines += ["## Replays", ""] + [f"- [{r}](10_report/{r}) (meshcat, self-contained HTML)" for r in replays] + [""]
    _atomic_write_text(root / "report.md", "\n".join(lines))
    return {"report": str(root / "report.md"), "replays": replays}


def _workers_table(done: dict[str, Any]) -> list[str]:
    """report.md's table of each simulating stage's rollouts, the workers' busy share and the batches' width."""
    rows = [(name, rec["summary"]["executor"]) for name, rec in done.items() if rec and rec["summary"].get("executor")]
    if not rows:
        return []
    lines = ["## Rollouts and workers", "",
             "Busy share: of the workers' time while simulating and over the whole stage. Width: rollouts per batch (what a "
             "larger pool could run at once); fill: the share of a 16- or 64-worker pool those batches could keep busy at best.", "",
             "| stage | workers | rollouts | rollouts/s | busy (simulating / stage) | batches | width mean / max | fill 16 / 64 |",
             "|---|---|---|---|---|---|---|---|"]
    for name, ex in rows:
        lines.append(f"| {name} | {ex['workers']} | {ex['rollouts']} | {ex['rollouts_per_s']} | {_short(ex['busy_share'])} / "
                     f"{_short(ex.get('stage_busy_share'))} | {ex.get('batches', '-')} | {ex.get('width_mean', '-')} / {ex.get('width_max', '-')} | "
                     f"{ex.get('fill_16_workers', '-')} / {ex.get('fill_64_workers', '-')} |")
    return lines + [""]


def _short(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, dict):
        return ", ".join(f"{k}: {_short(v)}" for k, v in value.items())
    return str(value)


STAGES: list[tuple[str, Callable[[Context, Path], dict[str, Any]]]] = [
    ("label", stage_label),
    ("segment", stage_segment),
    ("imitate", stage_imitate),
    ("refine", stage_refine),
    ("transfer", stage_transfer),
    ("diagnose", stage_diagnose),
    ("transfer_refined", stage_transfer_refined),
    ("template", stage_template),
    ("pool", stage_pool),
    ("report", stage_report),
]
