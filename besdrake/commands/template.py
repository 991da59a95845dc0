"""``besdrake template ACTION``: behaviour templates (contextual policy search over two meta-parameters).

* ``train BASE --pool DIR --name NAME``: learn a template from a base DMP (a refined throw, e.g.
  ``OUT/run0/refined.dmp.json`` of ``besdrake refine``; ``default`` = the built-in default throw
  fitted as a DMP, :func:`~besdrake.tasks.throwing.template_base.default_template_base`) with BO-CPS (``--method es|ucb``) or ACES, evaluate it on the paper's 16 test
  contexts and add it to the pool. The search is resumable: it lives in ``DIR/runs/NAME``.
* ``eval NAME --pool DIR``: mean distance over the 16 test contexts (simulated).
* ``instantiate NAME --pool DIR --target X Y [--plan-out FILE]``: the motion plan for a target.
* ``list --pool DIR``: the templates of a pool with their provenance.

Targets are (x forward, y lateral) in m, COMPI at the origin facing +x.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from besdrake._io import save_figure as _save_figure

COMMAND = ("template",)
HELP = "behaviour templates: train (BO-CPS/ACES), evaluate, instantiate and list a template pool"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("action", choices=("train", "eval", "instantiate", "list"))
    parser.add_argument("name_or_base", nargs="?", help="train: base DMP file or 'default'; eval/instantiate: template name")
    parser.add_argument("--pool", type=Path, default=Path("runs/templates"), help="template pool folder")
    parser.add_argument("--name", default=None, help="train: name of the new template (default: method_seed); eval/instantiate: the template (instead of the positional name)")
    parser.add_argument("--method", choices=("es", "ucb", "aces", "creps"), default="es", help="es: BO-CPS entropy search; ucb: upper confidence bound; aces: active context selection; creps: C-REPS baseline")
    parser.add_argument("--episodes", type=int, default=80)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--joint1-mode", choices=("rotate", "goal"), default="rotate", help="rotate: the joint-1 start moves with its goal (default); goal: the paper-literal goal only")
    parser.add_argument("--time-mode", choices=("scale", "raw"), default="scale",
                        help="scale: the execution time plays the base's path slower or faster (default); raw: only the DMP's execution time changes")
    parser.add_argument("--probes", type=int, default=None,
                        help="rollouts of the base that set the meta-parameter box and the reward model's prior (default 7, at most a quarter of --episodes; 0: none)")
    parser.add_argument("--extend-probes", type=int, default=None, metavar="N",
                        help="train: N more probes beyond the slowest execution time (up to 2x it) where the slowest still lands "
                             "beyond the context box's nearest target; the box follows them (default 0; besdrake learn: 2)")
    parser.add_argument("--follow-through", default=None, metavar="S",
                        help="train: s after the base's release (thrown once at its own speed) from which a plan that breaks a joint "
                             "limit is played slower until it keeps them (the arm's follow-through no longer moves the ball); 'none': "
                             "the whole throw played uniformly (default 0.05)")
    parser.add_argument("--robust-sd", type=float, default=0.0, metavar="M",
                        help="train: m per axis of the lab's setup scatter (the ball's placement) that each episode is rewarded "
                             "over: its expected squared miss over the task's quadrature (default 0: the setup as designed; "
                             "besdrake learn: 0.002)")
    parser.add_argument("--overwrite", action="store_true", help="train: replace a template of the same name")
    parser.add_argument("--target", "--context", dest="target", nargs=2, type=float, metavar=("X", "Y"), help="instantiate: target (x forward, y lateral), m")
    parser.add_argument("--plan-out", type=Path, default=None, help="instantiate: write the motion plan JSON here")
    from besdrake.sim.cliutil import add_backend_arguments

    add_backend_arguments(parser)
    parser.add_argument("--scenario", default="nominal")
    parser.add_argument("--no-figures", action="store_true")
    parser.add_argument("--quiet", action="store_true")
    parser.add_argument("--json", action="store_true", help="print the result as one JSON object")


def _executor(args):
    from besdrake.cli import UserError
    from besdrake.sim.cliutil import executor_from_args
    from besdrake.sim.executors import ExecutorError
    from besdrake.sim.scenario import ScenarioError

    try:
        return executor_from_args(args, args.scenario)
    except (ScenarioError, ExecutorError) as err:
        raise UserError(str(err)) from None


def _emit(args, data: dict, text: str) -> None:
    print(json.dumps(data, default=float) if args.json else text)


def run(args: argparse.Namespace) -> int:
    import logging

    from besdrake.cli import UserError
    from besdrake.search.templates import TemplateError, TemplatePool

    logging.getLogger("drake").setLevel(logging.ERROR)
    try:
        pool = TemplatePool(args.pool)
        if args.action == "list":
            data = {"pool": str(args.pool), "templates": {n: pool.provenance(n) for n in pool.names()}}
            _emit(args, data, "\n".join(f"{n}: {json.dumps(p)}" for n, p in data["templates"].items()) or f"{args.pool}: empty pool")
            return 0
        if not args.name_or_base and args.action != "train" and args.name:
            args.name_or_base = args.name
        if not args.name_or_base:
            raise UserError(f"template {args.action} needs a {'base DMP' if args.action == 'train' else 'template name'}")
        if args.action == "train":
            return _train(args, pool)
        template = pool.get(args.name_or_base)
        if args.action == "instantiate":
            if args.target is None:
                raise UserError("template instantiate needs --target X Y")
            plan = template.instantiate(args.target)
            if args.plan_out is not None:
                plan.save(args.plan_out)
            data = {"template": template.name, "target_m": list(args.target), "meta_parameters": plan.meta,
                    "duration_s": plan.duration, "plan": str(args.plan_out) if args.plan_out else None,
                    "within_limits": plan.check_limits(template.meta.robot.limits).ok}
            _emit(args, data, f"{template.name} -> target {args.target}: execution time {plan.meta['execution_time']:.3f} s, "
                              f"joint-1 goal {plan.meta['goal_joint1']:.3f} rad" + (f"; plan: {args.plan_out}" if args.plan_out else ""))
            return 0
        # eval
        from besdrake.search.templates import evaluate_template

        with _executor(args) as ex:
            ev = evaluate_template(template, ex)
        data = {"template": template.name} | ev.summary()
        _emit(args, data, f"{template.name}: mean distance over the 16 test contexts {data['mean_distance_cm']:.2f} cm")
        return 0
    except TemplateError as err:
        raise UserError(str(err)) from None


def _follow_through_after(value: str | None) -> float | None:
    """``--follow-through``: seconds within [0, 1] (default: the throwing task's ``FOLLOW_THROUGH_AFTER``), or None for
    'none'."""
    import numpy as np

    from besdrake.cli import UserError
    from besdrake.tasks.throwing.template_base import FOLLOW_THROUGH_AFTER

    if value is None:
        return FOLLOW_THROUGH_AFTER
    if str(value).strip().lower() == "none":
        return None
    try:
        after = float(value)
    except ValueError:
        after = float("nan")
    if not (np.isfinite(after) and 0.0 <= after <= 1.0):
        raise UserError(f"--follow-through must be a time within [0, 1] s or 'none', got {value!r}")
    return after


def _train(args, pool) -> int:
    from besdrake.cli import UserError
    from besdrake.imitation import DMPParameterError, load_dmp
    from besdrake.search.loop import ResumeError
    from besdrake.search.templates import DEFAULT_PROBES, EXTEND_PROBES, PAPER_MEAN_CM, evaluate_template, train_template
    from besdrake.task import scenario_scatter
    from besdrake.tasks.throwing.template_base import TEMPLATE_BASE_WEIGHTS, default_template_base, follow_through_phase

    if args.episodes < 1:
        raise UserError(f"--episodes must be >= 1, got {args.episodes}")
    if args.probes is not None and args.probes < 0:
        raise UserError(f"--probes must be >= 0, got {args.probes}")
    if args.extend_probes is not None and not 0 <= args.extend_probes <= 10:
        raise UserError(f"--extend-probes must be within [0, 10], got {args.extend_probes}")
    if not (math.isfinite(args.robust_sd) and 0.0 <= args.robust_sd <= 0.05):
        raise UserError(f"--robust-sd must be within [0, 0.05] m, got {args.robust_sd}")
    after = _follow_through_after(args.follow_through)
    name = args.name or f"{args.method}_seed{args.seed}"
    if name in pool and not args.overwrite:
        raise UserError(f"{args.pool} already holds a template {name!r} (use --overwrite or another --name)")
    if args.name_or_base == "default":
        base, base_source = default_template_base(), f"default_template_base (default throw, amplitude 0.6, {TEMPLATE_BASE_WEIGHTS} weights per joint)"
    else:
        try:
            base, base_source = load_dmp(args.name_or_base), str(Path(args.name_or_base).resolve())
        except DMPParameterError as err:
            raise UserError(str(err)) from None
    show = not args.quiet and sys.stderr.isatty()
    bar = None
    if show:
        from tqdm import tqdm

        bar = tqdm(total=args.episodes, desc=f"template {name}", unit="ep", file=sys.stderr)

    def progress(n: int, reward: float) -> None:
        if bar is not None:
            bar.update(n - bar.n)
            bar.set_postfix(reward=f"{reward:.3f}")

    run_dir = args.pool / "runs" / name
    t0 = time.perf_counter()
    checkpoints = tuple(sorted({e for e in (20, 40, 60, args.episodes) if e <= args.episodes}))
    try:
        with _executor(args) as ex:
            follow = follow_through_phase(base, ex, ex.scenario.robot, after) if args.time_mode == "scale" else None
            training = train_template(base, ex, args.method, args.episodes, args.seed, name, run_dir,
                                      joint1_mode=args.joint1_mode, checkpoints=checkpoints, time_mode=args.time_mode,
                                      probes=DEFAULT_PROBES if args.probes is None else args.probes, follow_through=follow,
                                      extend_probes=EXTEND_PROBES if args.extend_probes is None else args.extend_probes,
                                      provenance={"base_dmp": base_source, "run_dir": str(run_dir)}, progress=progress,
                                      scatter=scenario_scatter(ex.scenario, args.robust_sd))
            ev = evaluate_template(training.template, ex)
    except ResumeError as err:
        raise UserError(f"{run_dir}: {err}") from None
    finally:
        if bar is not None:
            bar.close()
    training.template.provenance["test_mean_distance_cm"] = 100.0 * ev.mean_distance
    path = pool.add(training.template, overwrite=args.overwrite)
    data = {
        "template": name, "file": str(path), "method": args.method, "episodes": int(training.template.provenance["n_episodes"]),
        "probe_rollouts": int(training.template.provenance["n_probe_rollouts"]),
        "failed_episodes": int(training.loop.n_failed), "resumed": bool(training.loop.resumed),
        "test": ev.summary(), "curve_mean_distance_cm": {str(k): 100.0 * v for k, v in training.curve.items()},
        "paper_real_robot_mean_cm": PAPER_MEAN_CM.get(args.method), "wall_time_s": time.perf_counter() - t0,
    }
    if not args.no_figures:
        data["learning_curve"] = str(_plot(training, ev, args.pool / "runs" / name / "learning_curve.png"))
    _emit(args, data, f"{name}: mean distance over the 16 test contexts {data['test']['mean_distance_cm']:.2f} cm "
                      f"after {data['episodes']} episodes ({data['failed_episodes']} failed); saved {path}")
    return 0


def _plot(training, ev, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    loop = training.loop
    fig, ax = plt.subplots(figsize=(6, 4))
    episodes = np.arange(1, loop.rewards.size + 1)
    dist = np.sqrt(np.maximum(-np.where(loop.failed, np.nan, loop.rewards), 0.0))
    ax.plot(episodes, 100 * dist, ".", ms=4, color="0.6", label="training episode")
    if training.curve:
        ks = sorted(training.curve)
        ax.plot(ks, [100 * training.curve[k] for k in ks], "o-", label="mean over 16 test contexts")
    ax.set_xlabel("episode")
    ax.set_ylabel("distance to target (cm)")
    ax.set_yscale("log")
    ax.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    _save_figure(fig, path, dpi=100)
    plt.close(fig)
    return path
