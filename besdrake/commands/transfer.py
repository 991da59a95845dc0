"""``besdrake transfer``: the Transferability Approach between a simulation scenario and a lab."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from besdrake._io import write_text as _atomic_write_text

COMMAND = ("transfer",)
HELP = "refine throws with the Transferability Approach: search in simulation, transfer the plans most likely to hit to the lab"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--lab", type=Path, required=True, help="virtual lab YAML (diagrams/labs/*.yaml)")
    parser.add_argument("--seeds", type=Path, nargs="+", required=True,
                        help="DMP files (*.dmp.json) or folders of them: throws refined in simulation, the best first (the "
                             "search's parameterization; seeds refined from another imitated throw are left out)")
    parser.add_argument("--scenario", default="nominal", help="simulation scenario (name or YAML, e.g. a refined one from 'besdrake diagnose')")
    parser.add_argument("--target", type=float, nargs=2, default=(2.0, 0.0), metavar=("X", "Y"), help="target on the floor (m)")
    parser.add_argument("--out", type=Path, default=Path("runs/transfer"), help="output folder (resumable): lab log, state, summary")
    parser.add_argument("--seed", type=int, default=0, help="seed of the search")
    parser.add_argument("--max-transfers", type=int, default=25)
    parser.add_argument("--population", type=int, default=50)
    from besdrake.sim.cliutil import add_backend_arguments

    add_backend_arguments(parser, workers=1)
    parser.add_argument("--plugin", action="append", default=[], help="module registering further effects (for the lab)")
    parser.add_argument("--keep-going", action="store_true", help="do not stop at the first 3/3 success")
    parser.add_argument("--transfer-choice", choices=["likely", "predicted", "diverse"], default=None,
                        help="plan transferred after each generation: most likely to pass the 3/3 check, closest predicted "
                             "lab touchdown (sim + learned sim-to-lab offset) or the paper's most diverse (default: the library's)")
    parser.add_argument("--placement-sd", type=float, default=None, metavar="M",
                        help="throw-to-throw scatter of the ball's placement in the scoop, m per axis: every plan is simulated at 9 "
                             "placements and judged by its expected throw (default 0.002, the virtual lab's; 0: the nominal placement only)")
    parser.add_argument("--futility-p", type=float, default=None, metavar="P",
                        help="end the search early once the last 3 plans transferred were each predicted to pass the 3/3 check "
                             "with a probability below P (--transfer-choice likely; the lab is off by more than the search can "
                             "make up: diagnose it); default: never")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")


def _dmp_files(paths: list[Path]) -> list[Path]:
    files: list[Path] = []
    for p in paths:
        files += sorted(p.glob("*.dmp.json")) if p.is_dir() else [p]
    return files


def _load_seeds(args: argparse.Namespace):
    """The seed DMP files, the lab's configuration, the seed DMPs and the scenario's robot; UserError on bad input."""
    from besdrake.cli import UserError
    from besdrake.imitation.io import load_dmp
    from besdrake.plugins import PluginError, load_plugins
    from besdrake.sim.scenario import load_scenario
    from besdrake.tasks.throwing.lab import LabConfigError, load_lab_config

    files = _dmp_files(args.seeds)
    if not files:
        raise UserError(f"no *.dmp.json seed found in {[str(p) for p in args.seeds]}")
    try:
        load_plugins(args.plugin)
        cfg = load_lab_config(args.lab)
        dmps = [load_dmp(f) for f in files]
        robot = load_scenario(args.scenario).robot
    except (PluginError, LabConfigError, OSError, ValueError) as err:
        raise UserError(str(err)) from None
    template = dmps[0]
    if any(d.n_dims != template.n_dims or d.n_weights_per_dim != template.n_weights_per_dim for d in dmps):
        raise UserError("all seed DMPs must have the same number of joints and weights")
    if template.n_dims != robot.n_joints:
        raise UserError(f"the seed DMPs have {template.n_dims} joints, the scenario's robot {robot.name!r} {robot.n_joints}")
    return files, cfg, dmps, robot


def _search_config(args: argparse.Namespace):
    """The Transferability Approach's settings from the command line; UserError on a bad value."""
    from besdrake.cli import UserError
    from besdrake.transfer.transferability import TransferabilityConfig

    try:
        return TransferabilityConfig(
            target=tuple(args.target), population=args.population, max_transfers=args.max_transfers,
            stop_on_success=not args.keep_going,
            **({"transfer_choice": args.transfer_choice} if args.transfer_choice else {}),
            **({} if args.placement_sd is None else {"placement_sd": args.placement_sd}),
            futility_p=args.futility_p,
        )
    except ValueError as err:
        raise UserError(str(err)) from None


def _run_search(args: argparse.Namespace, cfg, param, scaling, seeds, config):
    """Run the Transferability Approach against the (gated) virtual lab, logging every lab trial in OUT/lab_log."""
    import numpy as np

    from besdrake.cli import UserError
    from besdrake.sim.cliutil import executor_from_args
    from besdrake.sim.effects import EffectError
    from besdrake.sim.executors import ExecutorError
    from besdrake.sim.scenario import ScenarioError
    from besdrake.tasks.throwing.lab import VirtualLab
    from besdrake.transfer.lab import SafetyGate
    from besdrake.transfer.log import LabLog, LogError
    from besdrake.transfer.transferability import TransferabilityApproach

    lab = SafetyGate(VirtualLab(cfg))
    args.out.mkdir(parents=True, exist_ok=True)
    log_dir = args.out / "lab_log"
    try:
        log = LabLog.open(log_dir) if (log_dir / "log.json").is_file() else LabLog.create(log_dir, lab.description(), run={"seed": args.seed})
        executor = executor_from_args(args, args.scenario)
        with executor:
            search = TransferabilityApproach(
                lambda theta: param.motion_plan(theta), seeds, scaling.scale, scaling.bounds, executor, lab,
                np.random.default_rng(args.seed), config, log=log, out_dir=args.out,
                progress=(lambda msg: print(msg, file=sys.stderr)) if not args.json else None,
            )
            return search.run()
    except (LogError, EffectError, ScenarioError, ExecutorError) as err:
        raise UserError(str(err)) from None


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from besdrake.imitation import shared_parameterization
    from besdrake.search.refinement import ParameterScaling

    files, cfg, dmps, robot = _load_seeds(args)
    param, kept = shared_parameterization(dmps, robot.joint_names)
    for i in sorted(set(range(len(dmps))) - set(kept)):
        print(f"besdrake: warning: {files[i]} is not a seed: its DMP differs from {files[0]}'s beyond the searched parameters "
              "(another imitated throw: goal velocity); give the best seed first", file=sys.stderr)
    files, dmps = [files[i] for i in kept], [dmps[i] for i in kept]
    scaling = ParameterScaling.for_dmp(dmps[0], robot.position_limits)
    seeds = np.array([param.to_vector(d) for d in dmps])
    config = _search_config(args)
    result = _run_search(args, cfg, param, scaling, seeds, config)
    summary = result.summary() | {"scenario": args.scenario, "lab": cfg.name, "seeds": [str(f) for f in files], "out": str(args.out)}
    if result.best_theta is not None:
        best = param.from_vector(result.best_theta)
        best.save(args.out / "best.dmp.json")
        param.motion_plan(result.best_theta).save(args.out / "best.plan.json")
    _atomic_write_text((args.out / "summary.json"), json.dumps(summary, indent=1, default=float))
    if args.json:
        print(json.dumps(summary, default=float))
    else:
        print(f"{summary['lab_trials']} lab trials; 3/3 success after {summary['transfers_until_success']} trials; "
              f"{summary['n_reliable_final_candidates']} of {len(summary['final_candidates'])} final candidates reliable; "
              f"summary: {args.out / 'summary.json'}")
    return 0
