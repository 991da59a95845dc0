#!/usr/bin/env python3
"""Episode benchmark of refinement (issue 27): CPU ms per episode split into DMP rollout, retiming/limits,
simulation, reward and overhead, and the ratio episode / rollout measured in the same run (target <= 2).

Imitates ``--imitated`` (default ``synthetic:0:1``, 8 throws; or folders / *.dmp.json files), starts from the best
imitated throw as ``besdrake refine`` does and refines it for ``--episodes`` on one process (see
``besdrake.tasks.throwing.episode_bench``). Prints the split, or one JSON object with ``--json``.

    python3 scripts/bench_episode.py --episodes 60
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--imitated", nargs="+", default=["synthetic:0:1"], help="imitation folders, *.dmp.json files or synthetic:S[:E]")
    ap.add_argument("--episodes", type=int, default=60, help="episodes to time (default 60: six generations)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--work", type=Path, default=None, help="folder for the imitation and the run (default: a temporary one)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args(argv)
    if args.episodes < 1:
        print("bench_episode: error: --episodes must be >= 1", file=sys.stderr)
        return 2
    from besdrake.cli import UserError
    from besdrake.commands.refine import collect_imitated
    from besdrake.imitation import load_dmp
    from besdrake.search.refinement import RefinementProblem, rank_starts
    from besdrake.sim.executors import make_executor
    from besdrake.sim.scenario import load_scenario
    from besdrake.tasks.throwing.episode_bench import run_episode_bench

    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        try:
            files = collect_imitated(args.imitated, work)
        except UserError as err:
            print(f"bench_episode: error: {err}", file=sys.stderr)
            return 2
        robot = load_scenario("nominal").robot
        problems = [RefinementProblem(robot, load_dmp(f)) for f in files]
        with make_executor("serial") as ex:
            best = rank_starts(problems, ex)[0][0]
        print(f"start: {files[best].name} (best of {len(files)} imitated throws)", file=sys.stderr)
        res = run_episode_bench(problems[best], n_episodes=args.episodes, seed=args.seed, out_dir=work / "run")
    print(json.dumps(res.to_dict()) if args.json else res.table())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
