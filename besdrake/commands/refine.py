"""``besdrake refine IMITATED...``: refine imitated throws in simulation until the ball lands near a target.

Inputs are the imitation's outputs (``besdrake imitate ... --out DIR``): folders holding ``*.dmp.json``
files, single ``*.dmp.json`` files, or ``synthetic:S[:E]`` (the imitation is run first, with the given
segmentation, into ``OUT/imitation``). All motion plans are simulated once; each run of CMA-ES starts
from the best of them (the paper: "all available motion plans"). Every run has its own resumable folder
``OUT/runK`` (episodes, optimizer state, per-episode touchdowns); calling the command again with the
same ``--out`` continues unfinished runs. Writes ``OUT/runK/refined.dmp.json`` (the best throw, a
template base for ``besdrake template``), ``OUT/learning_curve.png`` and ``OUT/summary.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from functools import partial
from pathlib import Path
from besdrake._io import write_text as _atomic_write_text

COMMAND = ("refine",)
HELP = "refine imitated throws (49 DMP parameters) with CMA-ES in simulation so the ball lands within 0.1 m of a target"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("imitated", nargs="+", help="imitation output folder(s), *.dmp.json file(s) or synthetic:SUBJECT[:EXPERIMENT]")
    parser.add_argument("--out", type=Path, default=Path("runs/refine"), help="run folder (resumable)")
    parser.add_argument("--target", nargs=2, type=float, default=[2.0, 0.0], metavar=("X", "Y"), help="target on the floor, m (x forward, y lateral); default 2 0")
    parser.add_argument("--runs", type=int, default=1, help="independent CMA-ES runs (seeds SEED, SEED+1, ...); the paper: 6")
    parser.add_argument("--episodes", type=int, default=2000, help="episode budget per run (the paper: at most 10000)")
    parser.add_argument("--popsize", type=int, default=10, help="CMA-ES population (default 10, measured better here; the paper: 20)")
    parser.add_argument("--sigma0", type=float, default=None, help="initial step size in normalised units (default: the refinement's DEFAULT_SIGMA0)")
    parser.add_argument("--meta-episodes", type=int, default=0,
                        help="episodes of a first CMA-ES stage over meta-parameters (joint offsets, goals, execution time) before all 49 (0: none)")
    parser.add_argument("--meta-sigma", type=float, default=1.0, help="initial step size of the meta-parameter stage")
    parser.add_argument("--separable", action=argparse.BooleanOptionalAction, default=None,
                        help="separable CMA-ES (a diagonal covariance, cma's CMA_diagonal); default: besdrake.search.refinement.DEFAULT_CMA_OPTIONS")
    parser.add_argument("--elitist", action=argparse.BooleanOptionalAction, default=None,
                        help="elitist CMA-ES (the best throw so far stays in the population); default: as DEFAULT_CMA_OPTIONS")
    parser.add_argument("--stagnation", type=int, default=None, metavar="G",
                        help="restart CMA-ES (fresh step size) when its best distance improved by less than STAGNATION_TOL (2 cm) in G generations; 0: never (default: DEFAULT_STAGNATION_GENERATIONS)")
    parser.add_argument("--restart-from", choices=("start", "best"), default="best",
                        help="where a restart begins: the best throw so far (default) or the start throw")
    parser.add_argument("--regimes", choices=("large", "bipop", "local"), default=None,
                        help="restart regimes: 'large' (every restart with the initial step), 'bipop' (small local restarts from the best throw "
                             "alternate with large ones) or 'local' (small restarts from the best throw; a large one only after --patience small "
                             "ones in a row brought no improvement); default: besdrake.search.refinement.DEFAULT_RESTART_REGIMES")
    parser.add_argument("--patience", type=int, default=None, metavar="K",
                        help="'local' regimes: small restarts in a row without improvement before a large one (default: DEFAULT_PATIENCE)")
    parser.add_argument("--scouts", type=int, default=None, metavar="K",
                        help="the first K attempts are independent short CMA-ES runs (--scout-generations each, from the --scout-starts best imitated throws), then the best "
                             "goes on; 0: none (default: besdrake.search.refinement.DEFAULT_SCOUTS)")
    parser.add_argument("--scout-generations", type=int, default=None, metavar="G",
                        help="generations of each scout, or of each rung of the race with --scout-halving (default: DEFAULT_SCOUT_GENERATIONS)")
    parser.add_argument("--scout-halving", action=argparse.BooleanOptionalAction, default=None,
                        help="race the scouts by successive halving: all run --scout-generations, the better half runs as many more, "
                             "... until one is left (default: besdrake.search.refinement.DEFAULT_SCOUT_HALVING)")
    parser.add_argument("--scout-starts", type=int, default=None, metavar="N",
                        help="scout k starts from the (k mod N)-th best imitated throw; 1: every scout from the best (default: DEFAULT_SCOUT_STARTS)")
    parser.add_argument("--run-starts", choices=("same", "diverse"), default="diverse",
                        help="with scouts: every run from the best imitated throws (same), or run k from the throws ranked "
                             "4k+1 to 4k+4 (diverse, the default: a later run searches other throw families)")
    parser.add_argument("--retime", action=argparse.BooleanOptionalAction, default=None,
                        help="stretch each candidate's execution time just enough to keep the velocity and acceleration limits "
                             "(default: besdrake.search.refinement.DEFAULT_RETIME)")
    parser.add_argument("--violation-offset", type=float, default=None,
                        help="reward offset (m) of a throw beyond any joint limit (default: ThrowReward's)")
    parser.add_argument("--popsize-growth", type=float, default=None, metavar="F",
                        help="IPOP-like: the k-th large restart has population POPSIZE * F**k (default: DEFAULT_POPSIZE_GROWTH)")
    parser.add_argument("--plain", action="store_true", help="the search before issue 5: plain CMA-ES, no restarts (overrides the search options above; "
                                                              "'--regimes large' is the default before the BIPOP regimes)")
    parser.add_argument("--dropped-penalty", type=float, default=None, help="reward penalty (m) of a ball that falls out of the scoop (default 0)")
    parser.add_argument("--stall-episodes", type=int, default=None, metavar="N",
                        help="end a run once its best gained less than 1 cm over its last N episodes, not before episode 400 "
                             "(besdrake.search.refinement.StallRule; besdrake learn uses 200); default: never")
    parser.add_argument("--switch-distance", type=float, default=None, metavar="M",
                        help="where the scout that won the race stalls farther than M m from the target, go on with the scout "
                             "the race eliminated (the next throw family); needs scouting; default: never")
    parser.add_argument("--races", type=int, default=1, metavar="R",
                        help="with --switch-distance: where the race's winner stalls farther than it, race the next four "
                             "imitated throws within the run's budget, up to R races per run (run k then starts from the "
                             "throws ranked 4kR+1 on); default: 1")
    parser.add_argument("--race-stall-episodes", type=int, default=None, metavar="N",
                        help="with --races: race the next four imitated throws also where the current race's best gained less "
                             "than 1 cm over its last N episodes (not before episode 2N of the race) while the run is still "
                             "farther than 0.1 m from the target; --stall-episodes then judges the current race alone (session 44's "
                             "benchmark: 200 or 150); default: never")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--continue-after-success", action="store_true", help="use the whole budget instead of stopping at the first success")
    from besdrake.sim.cliutil import add_backend_arguments

    add_backend_arguments(parser)
    parser.add_argument("--scenario", default="nominal", help="simulation scenario (name or YAML path)")
    parser.add_argument("--no-figures", action="store_true", help="do not write learning_curve.png")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")


def collect_imitated(sources: list[str], out: Path) -> list[Path]:
    """The *.dmp.json files named by ``sources`` (folders, files, synthetic:S[:E] imitated into ``out/imitation``)."""
    from besdrake.cli import UserError

    files: list[Path] = []
    for src in sources:
        if src.startswith("synthetic:"):
            files += _imitate_synthetic(src, out / "imitation")
            continue
        p = Path(src)
        if p.is_dir():
            found = sorted(p.glob("*.dmp.json"))
            if not found:
                raise UserError(f"{p}: no *.dmp.json files (run 'besdrake imitate ... --out {p}' first)")
            files += found
        elif p.is_file():
            files.append(p)
        else:
            raise UserError(f"{src}: no such file or folder")
    return files


def _imitate_synthetic(source: str, folder: Path) -> list[Path]:
    from besdrake.cli import UserError
    from besdrake.tasks.throwing.imitation import find_throws, imitate_recording, load_demonstration, prepare

    tag = source.replace(":", "_")
    done = folder / f"{tag}.done"
    if done.exists():
        return [folder / n for n in json.loads(done.read_text())]
    try:
        demos = load_demonstration(source)
    except ValueError as err:
        raise UserError(str(err)) from None
    names = []
    for name, rec, segments in demos:
        pre = prepare(rec)
        throws = find_throws(pre, segments=segments)
        for r in imitate_recording(name, pre, throws, out_dir=folder, simulate=False, figures=False):
            if r.error is None:
                names.append(f"{name}_throw{r.index}.dmp.json")
    _atomic_write_text(done, json.dumps(names))
    return [folder / n for n in names]


def search_options(args: argparse.Namespace) -> dict:
    """Keyword arguments of :func:`besdrake.search.refinement.refine` for the search options of the command line."""
    from besdrake.search.refinement import DEFAULT_CMA_OPTIONS, DEFAULT_STAGNATION_GENERATIONS, PLAIN_SEARCH

    if args.plain:
        return dict(PLAIN_SEARCH)
    options = dict(DEFAULT_CMA_OPTIONS)
    for flag, key in ((args.separable, "CMA_diagonal"), (args.elitist, "CMA_elitist")):
        if flag is not None:
            options[key] = bool(flag)
    options = {k: v for k, v in options.items() if v}
    stagnation = DEFAULT_STAGNATION_GENERATIONS if args.stagnation is None else args.stagnation
    if args.meta_episodes > 0:
        stagnation = 0 if args.stagnation is None else stagnation
    out = {"cma_options": options, "stagnation_generations": stagnation, "restart_from_best": args.restart_from == "best"}
    if args.regimes is not None:
        out["restart_regimes"] = args.regimes
    if args.popsize_growth is not None:
        out["popsize_growth"] = args.popsize_growth
    if args.patience is not None:
        out["patience"] = args.patience
    if args.scouts is not None:
        out["scouts"] = args.scouts
    if args.scout_generations is not None:
        out["scout_generations"] = args.scout_generations
    if args.scout_halving is not None:
        out["scout_halving"] = args.scout_halving
    return out


def _check_args(args: argparse.Namespace) -> None:
    """Refuse a bad number before anything runs (one UserError line)."""
    import numpy as np

    from besdrake.cli import UserError

    for name, v, lo in (("--runs", args.runs, 1), ("--episodes", args.episodes, 1), ("--popsize", args.popsize, 2), ("--workers", args.workers, 1)):
        if v < lo:
            raise UserError(f"{name} must be >= {lo}, got {v}")
    if args.sigma0 is None:
        from besdrake.search.refinement.settings import DEFAULT_SIGMA0

        args.sigma0 = DEFAULT_SIGMA0
    if not (np.isfinite(args.sigma0) and args.sigma0 > 0):
        raise UserError(f"--sigma0 must be > 0, got {args.sigma0}")
    if args.meta_episodes < 0 or not (np.isfinite(args.meta_sigma) and args.meta_sigma > 0):
        raise UserError(f"--meta-episodes must be >= 0 and --meta-sigma > 0, got {args.meta_episodes}, {args.meta_sigma}")
    if args.stagnation is not None and args.stagnation < 0:
        raise UserError(f"--stagnation must be >= 0, got {args.stagnation}")
    if args.patience is not None and args.patience < 1:
        raise UserError(f"--patience must be >= 1, got {args.patience}")
    if (args.scouts is not None and args.scouts < 0) or (args.scout_generations is not None and args.scout_generations < 1):
        raise UserError(f"--scouts must be >= 0 and --scout-generations >= 1, got {args.scouts}, {args.scout_generations}")
    if args.popsize_growth is not None and not (np.isfinite(args.popsize_growth) and args.popsize_growth >= 1):
        raise UserError(f"--popsize-growth must be >= 1, got {args.popsize_growth}")
    if not np.isfinite(args.target).all():
        raise UserError(f"--target must be finite, got {args.target}")
    if args.races < 1 or (args.races > 1 and (args.switch_distance is None or args.plain or args.scouts in (0, 1))):
        raise UserError(f"--races must be >= 1, and more than 1 needs --switch-distance and scouting; got {args.races}")
    if args.race_stall_episodes is not None and (args.races < 2 or args.race_stall_episodes < 1):
        raise UserError(f"--race-stall-episodes must be >= 1 and needs --races 2 or more; "
                        f"got {args.race_stall_episodes} with --races {args.races}")


def _problems(args: argparse.Namespace, files: list[Path]):
    """One refinement problem per imitated throw, and the number of scout start points."""
    from besdrake.cli import UserError
    from besdrake.imitation import DMPParameterError, load_dmp
    from besdrake.search.refinement import RefinementError, RefinementProblem, scout_starts_checked
    from besdrake.sim.scenario import ScenarioError, load_scenario
    from besdrake.tasks.throwing.reward import ThrowReward

    try:
        extra = {} if args.dropped_penalty is None else {"dropped_penalty": args.dropped_penalty}
        if args.violation_offset is not None:
            extra["violation_offset"] = args.violation_offset
        reward = ThrowReward(target=tuple(args.target), **extra)
        robot = load_scenario(args.scenario).robot
        problems = [RefinementProblem(robot, load_dmp(f), reward, retime=args.retime) for f in files]
        return problems, scout_starts_checked(args.scout_starts)  # before anything is simulated
    except (DMPParameterError, RefinementError, ScenarioError) as err:
        raise UserError(str(err)) from None


def _start(args: argparse.Namespace, files: list[Path], problems: list, executor, scout_starts: int) -> dict:
    """The ranked start points (``OUT/start.json``, written once; a resumed run must refine the same throws)."""
    import numpy as np

    from besdrake.cli import UserError
    from besdrake.search.refinement import rank_starts, simulated_order

    start_file = args.out / "start.json"
    start = None
    if start_file.exists():
        start = json.loads(start_file.read_text())
        if start["files"] != [str(f) for f in files] or start["target"] != list(args.target):
            raise UserError(f"{args.out} holds a refinement of other throws or another target; use another --out")
    if start is None or (scout_starts > 1 and "ranking" not in start):
        ranking = rank_starts(problems, executor)
        index, rec = ranking[0]
        start = {"files": [str(f) for f in files], "target": list(args.target), "index": index,
                 "start_distance_m": rec.distance, "start_touchdown_m": rec.touchdown, "start_flags": rec.flags,
                 "ranking": simulated_order(ranking)}
        _atomic_write_text(start_file, json.dumps(start, indent=1))
    return start


def _race_stall(args: argparse.Namespace, next_starts):
    """``--race-stall-episodes N`` as :func:`refine`'s ``race_stall`` (:func:`race_stall_rule`'s defaults); None without
    it or where the run has no further race."""
    from besdrake.search.refinement import race_stall_rule

    if args.race_stall_episodes is None or next_starts is None:
        return None
    return race_stall_rule(args.race_stall_episodes)


def _refine_run(k: int, args: argparse.Namespace, problem, executor, *, search: dict, starts, show: bool, next_starts=None):
    """Run ``k`` of the refinement into ``OUT/run{k}`` (resumable), its refined DMP saved beside it."""
    from besdrake.cli import UserError
    from besdrake.imitation import save_dmp
    from besdrake.search.loop import ResumeError
    from besdrake.search.refinement import RefinementError, StallRule, refine

    run_dir = args.out / f"run{k}"
    bar = None
    if show:
        from tqdm import tqdm

        bar = tqdm(total=args.episodes, desc=f"run {k + 1}/{args.runs}", unit="ep", file=sys.stderr)

    def progress(n: int, best: float, _wall: float) -> None:
        if bar is not None:
            bar.update(n - bar.n)
            bar.set_postfix(best_m=f"{best:.3f}")

    try:
        result = refine(problem, executor, args.episodes, seed=args.seed + k, out_dir=run_dir, sigma0=args.sigma0,
                        popsize=args.popsize, stop_on_success=not args.continue_after_success, progress=progress,
                        meta_episodes=args.meta_episodes, meta_sigma=args.meta_sigma, **search,
                        **({} if starts is None else {"starts": starts}),
                        stall=None if args.stall_episodes is None else StallRule(args.stall_episodes),
                        switch_distance=args.switch_distance, next_starts=next_starts, race_stall=_race_stall(args, next_starts))
    except (RefinementError, ResumeError) as err:
        raise UserError(str(err)) from None
    finally:
        if bar is not None:
            bar.close()
    save_dmp(result.best_dmp, run_dir / "refined.dmp.json")
    return result


def _summary(args: argparse.Namespace, files: list[Path], start: dict, runs: list, t_start: float) -> dict:
    """The refinement's ``summary.json`` (written here) and its learning curves unless ``--no-figures``."""
    import numpy as np

    summary = {
        "target_m": list(args.target),
        "n_imitated_throws": len(files),
        "start": start,
        "runs": [r.summary() | {"folder": str(args.out / f"run{k}"), "refined_dmp": str(args.out / f"run{k}" / "refined.dmp.json")} for k, r in enumerate(runs)],
        "success_rate": float(np.mean([r.success for r in runs])),
        "median_episodes_to_success": (float(np.median([r.episodes_to_success for r in runs if r.success])) if any(r.success for r in runs) else None),
        "wall_time_s": time.perf_counter() - t_start,
    }
    if not args.no_figures:
        from besdrake.search.refinement import plot_learning_curves

        summary["learning_curve"] = str(plot_learning_curves(runs, args.out / "learning_curve.png"))
    _atomic_write_text(args.out / "summary.json", json.dumps(summary, indent=1, default=float))
    return summary


def run(args: argparse.Namespace) -> int:
    import logging

    from besdrake.cli import UserError
    from besdrake.search.refinement import family_run, hybrid_run
    from besdrake.sim.cliutil import executor_from_args
    from besdrake.sim.executors import ExecutorError
    from besdrake.sim.scenario import ScenarioError
    from besdrake.sim.scheduler import run_concurrently

    logging.getLogger("drake").setLevel(logging.ERROR)
    _check_args(args)
    t_start = time.perf_counter()
    args.out.mkdir(parents=True, exist_ok=True)
    files = collect_imitated(args.imitated, args.out)
    if not files:
        raise UserError("no imitated throws to refine")
    problems, scout_starts = _problems(args, files)
    show = not args.quiet and sys.stderr.isatty()
    try:
        executor = executor_from_args(args, args.scenario)
    except (ScenarioError, ExecutorError) as err:
        raise UserError(str(err)) from None
    search = search_options(args)
    with executor:
        start = _start(args, files, problems, executor, scout_starts)
        order = start.get("ranking") or [int(start["index"])]
        diverse = args.run_starts == "diverse" and search.get("scouts") != 0 and not args.plain
        # Each run from its start throw, its scouts from the next ones (None with one start point).
        groups = [k * args.races if diverse else 0 for k in range(args.runs)]
        # one throw searched (its own problem) or each scout and race from its imitated throw itself (family_run)
        one = args.meta_episodes > 0 or args.plain or search.get("scouts") == 0
        runs_at = [(hybrid_run if one else family_run)(problems, order, g, args.races, scout_starts) for g in groups]
        start["run_start_throws"] = [int(r.index) for r in runs_at]
        # The runs are independent: run_concurrently merges their generations into one batch per round (same results).
        runs = run_concurrently(executor, [partial(_refine_run, k, args, r.problem, search=search, starts=r.starts, show=show,
                                                   next_starts=r.next_starts) for k, r in enumerate(runs_at)])
    summary = _summary(args, files, start, runs, t_start)
    if args.json:
        print(json.dumps(summary, default=float))
    else:
        for k, r in enumerate(runs):
            state = f"success after {r.episodes_to_success} episodes" if r.success else f"no success in {r.n_episodes} episodes"
            print(f"run {k}: {state}; best distance {r.best_distance:.3f} m; {r.wall_time:.0f} s")
        print(f"summary: {args.out / 'summary.json'}")
    return 0
