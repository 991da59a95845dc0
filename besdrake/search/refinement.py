"""Refinement in simulation: the 49-parameter throwing problem for policy search (paper section 3.1.5, step 1).

A throw imitated from a human (:class:`besdrake.imitation.DMP`, 49 parameters: start 6, goal 6,
forcing-term weights 36, execution time 1) usually just drops the ball near the robot. Refinement
changes all 49 parameters so the ball lands within :data:`SUCCESS_DISTANCE` of a target.

* :class:`ThrowReward` turns a rollout into a reward (m, to maximise)::

      reward = -|touchdown - target| - penalty(limits) [- never_released_penalty] [- dropped_penalty]

  ``penalty`` sums the plan's joint-limit violations (:meth:`besdrake.plan.MotionPlan.check_limits`:
  position in rad, velocity in rad/s, acceleration in rad/s^2), each weighted (m per unit), plus
  :attr:`ThrowReward.violation_offset` (m) as soon as any limit is violated, so that a plan beyond a
  limit never scores like a successful throw. A ball that never leaves the scoop has no touchdown:
  the reward is then the (shaped) distance of the ball's last position to the target plus
  ``never_released_penalty`` (the search still sees which plans bring the ball closer). A failed
  simulation (``sim_failed``) or a parameter vector that gives no DMP rollout is a failed episode:
  the reward is NaN and the search loop records it as failed (the optimizers penalise it). A ball that
  fell out of the scoop (``dropped_early``) can cost ``dropped_penalty`` (off by default, see
  :data:`DROPPED_PENALTY`).
* :class:`ParameterScaling` maps the optimizer's normalised space ``x`` to ``theta`` and back:
  ``theta = theta0 + scale * x``. One unit is :data:`POSITION_UNIT` rad for start/goal,
  :data:`TIME_UNIT` s for the execution time and, for each weight, the weight change that changes the
  joint's acceleration by :data:`ACCELERATION_UNIT` rad/s^2 at its basis centre (weights act through
  ``z * w / tau^2`` with the phase ``z`` decaying to 0.01, so late weights need ~100 times larger
  steps; imitated weights range over 1e0...1e4). Bounds: start and goal within the joint position
  limits, execution time in [:data:`MIN_EXECUTION_TIME`, :data:`MAX_EXECUTION_TIME`] s, weights within
  +-:data:`WEIGHT_BOUND_UNITS` units of the imitated value.
* :class:`RefinementProblem` evaluates batches of normalised candidates through a rollout executor
  (:func:`besdrake.sim.make_executor`), keeps a per-episode record, and :func:`refine` runs CMA-ES
  (population :data:`DEFAULT_POPSIZE` = 10; the paper used 20, see the constant's comment) through the
  resumable search loop (:func:`besdrake.search.loop.run_search`). The per-episode record
  (touchdown, distance, penalty, flags) goes to ``details.csv`` beside the loop's ``episodes.csv``,
  keyed by :func:`params_key`, so a resumed run knows the distances of the episodes before the restart.

Success of a run: the first episode whose touchdown is within :data:`SUCCESS_DISTANCE` of the target
with no limit violated (``penalty == 0``); :func:`refine` stops after that generation by default.

The search (:func:`make_optimizer`, defaults :data:`DEFAULT_CMA_OPTIONS`, :data:`DEFAULT_STAGNATION_GENERATIONS`):
*separable* CMA-ES (``cma``'s ``CMA_diagonal``: a diagonal covariance, whose per-parameter step sizes adapt about
``n`` times faster than a full covariance in 49 dimensions) that is *elitist* (``CMA_elitist``: the best throw so
far stays in the population) and restarts (:class:`~besdrake.search.cmaes.StagnationRestartCMAES`, fresh step size
``sigma0``, from the best throw so far) when its best distance has improved by less than :data:`STAGNATION_TOL`
over 10 generations, with *BIPOP restart regimes* (:data:`DEFAULT_RESTART_REGIMES`, see below), after four *scouts*
from the four best imitated throws raced by successive halving, on *retimed* candidates and a reward whose limit offset outweighs the target distance
(see "Scouting across throw families" below; ``"local"`` regimes are an option, measured, not better). Why: the successful throws lie far from the imitated one along a few parameters (goal of joint
2 raised by 1.2-2.3 rad, start of joint 3 lowered, execution time changed by up to 1 s; measured on the 10 best
throws of the plain runs), while the population's median throw lands 0.5-0.7 m from the target when its best lands
0.1-0.2 m away: plain CMA-ES learns those scales slowly and its mean creeps. Measured before choosing (800
episodes, seed 0, subjects 0-4, episodes to success or best distance in m; shared 2-core machine):
plain 0.18 / 0.33 / 411 / 0.29 / 0.32; separable 0.16 / 0.29 / 0.11 / 0.11 / 0.13; elitist 0.18 / 0.30 / 191 /
528 / 0.12; separable + elitist 0.16 / 0.43 / 169 / 687 / 0.18; the same with restarts from the best throw
(subjects 0, 1, 4) 0.15 / 0.46 / 434, restarts from the start throw instead 0.22 / 0.51 (subject 4 not run); separable with a
0.6 rad position unit 0.33 / 0.38 / 0.28 / 797 / 517; separable with population 6 0.25 / 0.20 / 600 / 659 / 0.12;
restarts from the next-best imitated throws (:func:`rank_starts`, :func:`restart_points`) 0.32 on subject 0.
Single runs: the differences are within the seed-to-seed spread. ``refine(**PLAIN_SEARCH)`` (``--plain`` on the
command line) is the search before (plain CMA-ES). All 10 subjects, 1500 episodes, seed 0
(``scripts/bench_refinement.py --runs 1 --episodes 1500 --backend serial``): goal reached for 7 of 10 (subjects
2-8: 169 / 761 / 434 / 350 / 930 / 1021 / 495 episodes), median 495; stalled at 0.15 / 0.43 / 0.21 m (subjects 0,
1, 9); median 83 s per run. Seed 1 (``--first-seed 1``): 7 of 10 (subjects 0 2 3 4 6 7 8: 213 / 111 / 1164 / 691 /
627 / 625 / 446), median 625; stalled at 0.14 / 0.10 / 0.21 m (subjects 1, 5, 9); median 99 s per run. Plain
CMA-ES, same benchmark: 6 of 10 (subjects 0 1 2 4 5 7: 1399 / 1118 / 411 / 1153 / 881 / 327), median 1000; seed 1
with 1000 episodes: 4 of 10. Restarts from the best throw do not leave a bad basin (subject 1: six attempts, all
0.43-0.51 m); restarts from the start throw instead (``--restart-from start``, subjects 1 and 9, seed 0, 1500
episodes) stall too, at 0.32 and 0.27 m. Those figures are for every restart with the full step ``sigma0``
(``restart_regimes="large"``, ``--regimes large``: the default before the BIPOP regimes).

BIPOP restart regimes (``restart_regimes="bipop"``, the default; Hansen 2009's alternation of small and large
restarts, triggered by stagnation): a restart is *small* (step ``sigma0 * 10**(-2u)``, ``u ~ U(0, 1)``, from the
best throw so far) while the small attempts have used fewer episodes than the large ones, else *large* (step
``sigma0``, from the best throw). Why: half of the stalled runs were *near misses* (best 0.10-0.17 m): every
restart with the full step threw the population 0.4-0.5 m away from the best throw (the attempts after a restart
reached only -0.13 to -0.50 m of reward on subject 5, seed 1, whose best stayed at 0.102 m for 1300 episodes), so
no attempt could refine the best basin; a small restart refines it. Screened on the hard cases (subjects 0, 1, 5,
9; seeds 0 and 1; 800 episodes; episodes to success or best distance in m; shared 2-core machine):
every restart large (the runs above, read at episode 800) 0.15 / 0.46 / 350 / 0.21 and 213 / 0.14 / 0.10 / 0.33,
2 of 8; BIPOP 0.17 / 0.48 / 350 / 0.13 and 213 / 0.13 / 221 / 717, 4 of 8; BIPOP with the large restarts from the
start throw instead 0.17 / 0.48 / 350 / 0.15 and 213 / 0.13 / 221 / 717, 4 of 8 (within 800 episodes a large
restart rarely comes: the first attempt runs 200-650 episodes and the small ones then get as many); a 2.5 times
larger initial step on start/goal and 2 times on the execution time (``cma``'s ``CMA_stds``) 0.20 / 0.50 / 0.35 /
0.69 and 0.12 / 0.52 / 0.72 / 0.66, 0 of 8 (larger steps break limits and drop the ball more often).
All 10 subjects, 1500 episodes (``scripts/bench_refinement.py --runs 1 --episodes 1500 --backend serial``, shared
2-core machine), BIPOP against every restart large (the figures above): seed 0: 6 of 10 (subjects 2 3 4 5 8 9: 169 /
1388 / 730 / 350 / 956 / 831 episodes), median 780.5, stalled at 0.109 / 0.366 / 0.178 / 0.106 m (subjects 0, 1, 6,
7); against 7 of 10, median 495; seed 1: 10 of 10 (subjects 0-9: 213 / 931 / 111 / 594 / 952 / 221 / 1394 / 723 /
338 / 717), median 655.5, against 7 of 10, median 625. Together 16 of 20 runs against 14 of 20, and every subject
reaches the goal in at least one of the two runs (subjects 1 and 9 never did before); the price: where a large
restart from the best throw found the goal (subjects 3, 4, 6, 7, 8 of seed 0), the small restarts that come first
delay it (seed 0: 434 -> 730, 495 -> 956, 761 -> 1388 episodes; 930 and 1021 -> no success in 1500), so the median
episodes to success is higher. Median wall time per run 134 s (seed 0) and 90 s (seed 1), 0.11-0.12 s per episode.
The issue's target (every run succeeds, median <= 500 episodes) is not met. A smaller share of small restarts
(``small_share=0.5``: small attempts while their episodes are fewer than half the large ones), on the runs where the
two differ (seed 0 subjects 3 4 6 7 8 9; seed 1 subjects 1 5 9): 976 / 901 / 0.202 m / 1163 / 0.153 m / 952 and
931 / 221 / 717, i.e. 4 of 6 (as BIPOP; every restart large: 5 of 6) and 3 of 3; not better, so not the default.

Scouting (``refine(scouts=3, scout_generations=12)``, ``--scouts 3``; every scout from the start throw -- measured here,
superseded by scouting across throw families below):
the first three attempts are independent CMA-ES runs from the start throw (step ``sigma0``, 12 generations = 120
episodes each, one after the other); the best of them goes on with its CMA-ES state as the first attempt proper, then
the BIPOP restarts follow. Why (measured on last session's 20 benchmark runs and probes of their best throws): the
near misses are *range-limited*: the best throws of the stalled seed-0 runs (subjects 0 1 6 7) land at x = 1.64-1.94 m
(target 2 m), released downwards (-8 to -19 degrees) at 2.0-3.1 m/s; probed on subject 0, seed 0 (best 0.109 m, x =
1.89 m): every start/goal/time parameter +-0.015 rad or s moves x by < 5 mm, random steps of 0.001-0.1 units only
shorten it; landing beyond 1.95 m within the limits is rare at all (0-24 of up to 1500 episodes
per run, 0 in every stalled run). So a
run's fate is mostly decided by the throw family its first attempt settles in, which no restart from the best throw
leaves (subject 1, seed 0: six attempts, 0.37-0.51 m). Scouting spends ~240 episodes on two more first attempts. A
small local restart from a near miss still finishes many runs (last session's BIPOP logs: 13 of 30 small restarts
from a best of 0.10-0.15 m reached the goal, in 8 generations on average, against 1 of 7 large ones), which is why
the BIPOP regimes stay. ``restart_regimes="local"`` (``--regimes local``: small restarts from the best throw, a large
one only after :data:`DEFAULT_PATIENCE` small ones in a row without a 2 cm improvement) was screened too and is not
the default. Screened on the hard cases (1500 episodes; seed 0 subjects 0 1 6 7, seed 1 subjects 1 6; episodes to
success or best distance in m; shared 2-core machine): BIPOP 0.109 / 0.366 / 0.178 / 0.106 and 931 / 1394, 2 of 6;
local 0.155 / 0.366 / 0.247 / 0.206 and 931 / 0.247, 1 of 6; scouting 0.150 / 783 / 0.107 / 1232 and 0.241 / 1415,
3 of 6 (subject 1 of seed 0 reaches the goal for the first time: its third scout found another family).
All 10 subjects, 1500 episodes (``scripts/bench_refinement.py --runs 1 --episodes 1500 --backend serial --scouts 3
--scout-generations 12``, shared 2-core machine), against BIPOP without scouting (the figures above): seed 0: 8 of 10
(subjects 1-5 7-9: 783 / 526 / 1447 / 1200 / 767 / 1232 / 239 / 775 episodes), median 779, stalled at 0.150 / 0.107 m
(subjects 0, 6), against 6 of 10, median 780.5; seed 1: 8 of 10 (subjects 2-9: 111 / 602 / 1437 / 490 / 1415 / 383 /
450 / 807), median 546, stalled at 0.170 / 0.241 m (subjects 0, 1), against 10 of 10, median 655.5. Together 16 of 20
runs as BIPOP, pooled median 771 against 720 episodes, and subject 0 reaches the goal in neither seed (BIPOP: every
subject in at least one of the two, which is what ``besdrake learn``'s two runs need); the price of scouting shows
where the first attempt would have succeeded soon (subject 2, seed 0: 169 -> 526; subject 0, seed 1: 213 -> no
success, the first scout was not the best after 120 episodes). Median wall time per run 75 s (seed 0) and 83 s
(seed 1), 0.07-0.09 s per episode (962 s and 980 s for the 10 runs of a seed). So scouting is not the default.
IPOP-like large restarts (``popsize_growth=2``, ``--popsize-growth 2``: the k-th large restart has population
10 * 2**k; the runs differ from BIPOP only from the second large attempt on), same benchmark: seed 0: 6 of 10
(subjects 0 2 3 4 5 7: 1470 / 169 / 1022 / 864 / 350 / 1020), median 942, stalled at 0.366 / 0.237 / 0.156 / 0.113 m
(subjects 1, 6, 8, 9); seed 1: 10 of 10 (213 / 931 / 111 / 594 / 985 / 221 / 1137 / 723 / 338 / 717), median 655.5;
together 16 of 20, pooled median 720, every subject in one of the two seeds: the same figures as BIPOP (other runs
fail), so not the default either. Median wall time per run 74 s and 48 s (970 s and 504 s per seed).

Scouting across throw families (the default since session 6: :data:`DEFAULT_SCOUTS` = 4 scouts of 12 generations
from the :data:`DEFAULT_SCOUT_STARTS` = 4 best imitated throws, :func:`scout_start_points`; candidates retimed,
:meth:`RefinementProblem.retimed`; ``ThrowReward.violation_offset`` 1 m instead of 0.2 m). Why: (1) the best throws
of the 20 BIPOP benchmark runs all sit on a limit (a joint at 0.95-1.0 of its velocity or acceleration limit) and
14-36% of their episodes broke one: a throw made faster than the limits allow is now slowed just enough (the
embodiment mapping's temporal scaling) instead of penalised; (2) scouts from the subject's other imitated throws
start in other throw families (a run's fate is set by the family its first attempt settles in, see above); (3) but
those throws break limits, and with a 0.2 m offset the search settled beyond them: seed 0, subject 1, scouts from the
four best throws without the other two changes: 95% of the episodes after the first scout broke a limit (the
acceleration of joint 5 by ~1 rad/s^2, at the end of the plan, where the DMP meets its goal velocity -- a stretch does
not lower that, so such plans are left as they are), best -0.31 reward with 0.01 m target distance, best within the
limits 1.01 m. With a 1 m offset a plan beyond a limit ranks below every plan within them that lands within 1 m.
All 10 subjects, seeds 0 and 1, 1500 episodes (``scripts/bench_refinement.py --runs 2 --episodes 1500 --backend
serial``, 2-core machine shared by two benchmarks; episodes to 0.1 m, or the best distance of a failed run):

    subject          0    1        2    3    4    5    6    7    8    9
    seed 0         678  1210     220  593  296  162  927  113  487  528
    seed 1         726  0.277 m  313 1274  357  581 1320  841   58  664

19 of 20 runs (seed 0: 10 of 10, median 507.5; seed 1: 9 of 10, median 664), pooled median 581 over the successes
(587 counting the failure as more than 1500); median wall time per run 41 s. The BIPOP default before: 16 of 20,
median 720. Ablations (same benchmark, 20 runs each unless said): scouts from the four best throws + retiming with
the 0.2 m offset: 15 of 20 (stalled: subject 0 seed 0, subject 1 and 6 both seeds), pooled median of successes 356;
the same with a retiming that kept a stretch even when it did not mend the plan: 17 of 20; scouts + 1 m offset
without retiming: 15 of 20, median 745 (stalled: subject 0 seed 0, subjects 1 and 6 both seeds); the 1 m offset alone
(BIPOP, no scouts, no retiming): 15 of 20, median 556 (the same five stall). Only the three together reach the goal with every subject in
both seeds but one run. The target (every run, median <= 500 episodes) is still not met: subject 1 seed 1 stalls at
0.277 m and the pooled median is 581.

Racing the scouts (the default since session 7: :data:`DEFAULT_SCOUT_HALVING`, rungs of
:data:`DEFAULT_SCOUT_GENERATIONS` = 4 generations). Why: the scouts one after the other cost 480 episodes before the
best goes on, most of the median; over the 44 session-6 benchmark runs that ran all four scouts, the scout ahead
after 4 generations (the better two of four) and then after 8 (the better of two) was the one ahead after 12 in 37
(84%). Successive halving (Jamieson & Talwalkar 2016) keeps that choice for 240 episodes: all four scouts run 4
generations, the better two 4 more each, the better one goes on. Same benchmark with the paper's budget of at most
10,000 episodes (``scripts/bench_refinement.py --runs 1 --first-seed S --backend serial``, seeds 0-3, 2-core machine
shared by up to four benchmarks; episodes to 0.1 m):

    subject          0     1     2    3    4    5     6     7    8    9
    seed 0        1046  1062   219  495  142  442   669   430  249  339
    seed 1        7272  3240   199  926  536  266  1601   391  487  321
    seed 2         264   312   165  365  298  193   694   344  174  799
    seed 3         440  2500   162  517  421  292  1080  1051  406 2471

40 of 40 runs reach the goal, median 425.5 episodes (35 of 40 within 1,500 episodes, 36 within 2,200); the
session-6 default (scouts one after the other, 12 generations each; ``--no-scout-halving --scout-generations 12``)
on the same seeds: 40 of 40, median 534.5 (38 within 1,500; seeds 2 and 3 measured in the same session, seeds 0 and 1
in session 6 with the one run that did not reach the goal in 1,500 episodes resumed: 2,426): the race takes the
median to 0.80 of it (per seed 436 / 511.5 / 305 / 478.5 against 507.5 / 695 / 524.5 / 574) and leaves a few more runs
long (7,272 and 3,240 episodes on seed 1; the longest of the session-6 default: 9,518). Measured alternatives: rungs
of 6 generations (360 episodes of scouting): 3 of the first 4 runs failed to reach the goal in 1,500 episodes
(stopped); the race with large restarts from the scouts' start points in turn (``restart_from_best=False``, seeds 0
and 1): 20 of 20, median 464.5, the longest runs shorter (1,833 and 1,131 instead of 7,272 and 3,240) and others
longer (2,217 and 3,608 instead of 926 and 1,601) -- not the default.

Options measured against plain CMA-ES (seed 0, synthetic subjects 0-4, shared 2-core machine; see
``scripts/bench_refinement.py``): a meta-parameter stage first (:func:`meta_basis`, :class:`~besdrake.search.cmaes.StagedCMAES`:
``refine(meta_episodes=...)``), a dropped-ball penalty (:data:`DROPPED_PENALTY`), a coarser position unit and an
execution time bounded by the imitated one. None beat plain CMA-ES on the 49 parameters, so the default stays
plain CMA-ES (1500 episodes: default 857 / 1450 / - / - / 462 episodes to success on subjects 0-4, stalled at
0.41 and 0.16 m; 300 meta episodes first: - / - / - / - / 977, stalled at 0.29, 0.34, 0.50 and 0.18 m). Why runs stall (measured): every imitated throw drops the ball within 0.37 s
(scoop tilted beyond its walls at the start), and from there the search either climbs "drop it farther out"
(the ball falls from the outstretched arm, up to ~1.4 m) or finds real throws released downwards at 2-3 m/s
that land 1.5-1.7 m out, which it slowly lengthens (execution time up by 0.5-1.9 s); the successful throws
are released at ~3.5 m/s. These figures are for the paper-literal imitation
(``ImitationOptions(hold_cone_deg=None)``); the embodiment mapping now keeps the scoop upright enough to
hold the ball, which removes the first dead end (same benchmark, seeds 0 and 1: 10 of 20 runs reach the
goal against 5 of 20).
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from besdrake._io import save_figure as _save_figure
from besdrake._io import write_json
from besdrake.imitation import DMP, DMPParameterError, DMPParameterization
from besdrake.plan import MotionPlan, PlanError
from besdrake.robot import JointLimits, Robot

#: The goal of refinement: touchdown within this distance (m) of the target, no limit violated.
SUCCESS_DISTANCE = 0.1
#: Default target (x forward, y lateral; m) on the floor: 2 m in front of the robot.
DEFAULT_TARGET = (2.0, 0.0)
#: Minimum execution time (s) of a throw (the paper's), maximum: our sane choice.
MIN_EXECUTION_TIME = 0.95
MAX_EXECUTION_TIME = 4.0
#: Units of the normalised space (see module docstring).
POSITION_UNIT = 0.3  # rad
TIME_UNIT = 0.3  # s
ACCELERATION_UNIT = 2.0  # rad/s^2 at a basis centre
WEIGHT_BOUND_UNITS = 50.0
#: Population size and budget of the paper's refinement runs.
PAPER_POPSIZE = 20
PAPER_MAX_EPISODES = 10_000
#: Our default population: 10. Measured on synthetic subjects 0, 1, 2 (seed 0, 1000-1500 episodes, shared
#: CPU): population 10 reached 0.05 / 0.16 / 0.41 m, population 20 0.51 / 0.31 / 0.51 m (more generations
#: for the same number of episodes matter more here than a larger sample per generation).
DEFAULT_POPSIZE = 10
#: Plan sampling step (s) for the DMP rollout that the simulation executes.
PLAN_DT = 0.01
#: Reward penalty (m) of a ball that fell out of the scoop (``dropped_early``), off by default. Why it exists:
#: every imitated throw of the 10 default synthetic subjects drops the ball within 0.37 s (the scoop starts
#: tilted by 0.8-1.8 rad, beyond its 45-degree walls; imitation does not know about the ball), and a search can
#: climb the "drop it farther out" hill (subject 2, 400 episodes: best = a ball dropped at t = 0.13 s from the
#: outstretched arm, landing at x = 1.39 m). Measured with a 1 m penalty (seed 0, 1000 episodes): the search holds
#: the ball within ~300 episodes but then stalls at 1.5-1.7 m with throws released downwards (best 0.52 / 0.28 /
#: 0.43 / 0.20 m on subjects 0-3), while without it subject 0 succeeds after 857 episodes; so not the default.
DROPPED_PENALTY = 0.0
#: A restart attempt (``refine(stagnation_generations=...)``) stalls when its best reward improved by less than this (m).
STAGNATION_TOL = 0.02
#: Default search of :func:`refine` (see the module docstring for the measurements): ``cma`` options and the
#: stagnation restarts (generations; 0: none). ``refine(cma_options={}, stagnation_generations=0)`` is plain CMA-ES.
DEFAULT_CMA_OPTIONS: dict[str, Any] = {"CMA_diagonal": True, "CMA_elitist": True}
DEFAULT_STAGNATION_GENERATIONS = 10
#: Restart regimes of the stagnation restarts (:class:`~besdrake.search.cmaes.StagnationRestartCMAES`'s ``regimes``):
#: ``"large"`` (every restart with the initial step; the default before) or ``"bipop"`` (small local restarts from the
#: best throw alternate with large ones; 16 of 20 benchmark runs against 14 of 20, see the module docstring) or ``"local"`` (small
#: restarts unless stuck: 1 of 6 hard cases against BIPOP's 2 of 6, not the default), and the population growth of the
#: large restarts (1: none; IPOP-like 2: 16 of 20 runs, pooled median 720 episodes, the same as without; module docstring).
RESTART_REGIMES = ("large", "bipop", "local")
DEFAULT_RESTART_REGIMES = "bipop"
DEFAULT_POPSIZE_GROWTH = 1.0
#: ``"local"`` regimes: small restarts in a row that did not improve the best throw by :data:`STAGNATION_TOL` before a large one.
DEFAULT_PATIENCE = 2
#: Scouting (:class:`~besdrake.search.cmaes.StagnationRestartCMAES`'s ``scouts``): the first attempts are this many
#: independent short CMA-ES runs; the best goes on. Four, from the four best imitated throws
#: (:data:`DEFAULT_SCOUT_STARTS`), with retiming and the limit offset of :class:`ThrowReward` (see "Scouting across
#: throw families" in the module docstring), raced by successive halving (:data:`DEFAULT_SCOUT_HALVING`) in rungs of
#: :data:`DEFAULT_SCOUT_GENERATIONS` generations: 240 episodes of scouting instead of 480 (see "Racing the scouts").
DEFAULT_SCOUTS = 4
#: Generations of a rung of the race (of each scout without :data:`DEFAULT_SCOUT_HALVING`; 12 in session 6).
DEFAULT_SCOUT_GENERATIONS = 4
#: Where the scouts start (:func:`scout_start_points`): scout ``k`` from the ``(k mod N)``-th best imitated throw; 1: every
#: scout from the start throw.
DEFAULT_SCOUT_STARTS = 4
#: Race the scouts by successive halving (rungs of :data:`DEFAULT_SCOUT_GENERATIONS`; see
#: :class:`~besdrake.search.cmaes.StagnationRestartCMAES`) instead of running each to the end one after the other.
DEFAULT_SCOUT_HALVING = True
#: The search before issue 5 (plain CMA-ES, no restarts): keyword arguments of :func:`refine`.
PLAIN_SEARCH: dict[str, Any] = {"cma_options": {}, "stagnation_generations": 0}
#: Offset (rad) of the whole movement per unit of the meta-parameter stage (:func:`meta_basis`).
META_OFFSET_UNIT = 1.0

#: Retiming (``RefinementProblem(retime=True)``): at most this many stretches (each checked), each stretching by the
#: measured peak ratio times ``1 + RETIME_MARGIN`` (the DMP's goal velocity makes a stretch only nearly uniform).
RETIME_ROUNDS = 4
#: Whether a :class:`RefinementProblem` retimes its candidates unless told (``retime=``).
DEFAULT_RETIME = True
RETIME_MARGIN = 0.002

DETAILS_FILE = "details.csv"
PROBLEM_FILE = "problem.json"


class RefinementError(ValueError):
    """Bad input to refinement: a malformed template, target, scaling or run folder."""


# ---------------------------------------------------------------------------------------------
# reward
# ---------------------------------------------------------------------------------------------
@dataclass
class RewardBreakdown:
    """One episode's reward and its parts (m; ``reward`` is NaN for a failed episode)."""

    reward: float
    distance: float
    penalty: float
    touchdown: tuple[float, float] | None
    flags: list[str] = field(default_factory=list)
    message: str = ""

    @property
    def failed(self) -> bool:
        return not np.isfinite(self.reward)

    @property
    def success(self) -> bool:
        """Touchdown within :data:`SUCCESS_DISTANCE` of the target and no limit violated."""
        return (not self.failed) and self.touchdown is not None and self.distance < SUCCESS_DISTANCE and self.penalty == 0.0


@dataclass
class ThrowReward:
    """``reward = -distance(touchdown, target) - limit penalties`` (see module docstring); SI units.

    Weights are in m per rad (position), m per rad/s (velocity) and m per rad/s^2 (acceleration).
    """

    target: tuple[float, float] = DEFAULT_TARGET
    position_weight: float = 2.0
    velocity_weight: float = 1.0
    acceleration_weight: float = 0.1
    violation_offset: float = 1.0
    never_released_penalty: float = 1.0
    dropped_penalty: float = DROPPED_PENALTY

    def __post_init__(self) -> None:
        try:
            target = np.asarray(self.target, dtype=float).ravel()
        except (TypeError, ValueError):
            target = np.full(1, np.nan)
        if target.shape != (2,) or not np.isfinite(target).all():
            raise RefinementError(f"target must be two finite numbers (x forward, y lateral; m), got {self.target!r}")
        self.target = (float(target[0]), float(target[1]))
        for name in ("position_weight", "velocity_weight", "acceleration_weight", "violation_offset", "never_released_penalty", "dropped_penalty"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise RefinementError(f"{name} must be a finite number >= 0, got {v!r}")

    def penalty(self, plan: MotionPlan, limits: JointLimits) -> float:
        """Limit penalty (m) of ``plan`` against the robot's ``limits``: weighted sum of the violations, plus the
        offset if any."""
        rep = plan.check_limits(limits)
        total = (
            self.position_weight * float(rep.position.sum())
            + self.velocity_weight * float(rep.velocity.sum())
            + self.acceleration_weight * float(rep.acceleration.sum())
        )
        return total + self.violation_offset if not rep.ok else 0.0

    def __call__(self, plan: MotionPlan, outcome, limits: JointLimits) -> RewardBreakdown:
        """Reward of ``outcome`` (a :class:`besdrake.sim.Outcome`) of ``plan`` on a robot with ``limits``."""
        flags = [k for k, v in outcome.flags.items() if v]
        if outcome.flags.get("sim_failed"):
            return RewardBreakdown(np.nan, np.nan, np.nan, None, flags, outcome.message or "simulation failed")
        penalty = self.penalty(plan, limits)
        target = np.asarray(self.target)
        if outcome.touchdown is not None and np.isfinite(outcome.touchdown).all():
            td = np.asarray(outcome.touchdown, dtype=float)[:2]
            distance = float(np.linalg.norm(td - target))
            dropped = self.dropped_penalty if outcome.flags.get("dropped_early") else 0.0
            return RewardBreakdown(-distance - penalty - dropped, distance, penalty, (float(td[0]), float(td[1])), flags, outcome.message)
        # never released: shaped by where the ball is at the end of the simulation
        path = np.asarray(outcome.ball_path, dtype=float).reshape(-1, 3)
        path = path[np.isfinite(path).all(axis=1)]
        if path.size == 0:
            return RewardBreakdown(np.nan, np.nan, np.nan, None, flags, "no ball position recorded")
        distance = float(np.linalg.norm(path[-1, :2] - target))
        reward = -distance - penalty - self.never_released_penalty
        return RewardBreakdown(reward, distance, penalty, None, flags, outcome.message or "never released")

    def to_dict(self) -> dict[str, Any]:
        d = {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}
        if d["dropped_penalty"] == 0.0:
            del d["dropped_penalty"]  # off: the record of earlier runs (resume checks compare it)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "ThrowReward":
        try:
            return cls(**{k: (tuple(v) if k == "target" else float(v)) for k, v in d.items()})
        except TypeError as err:
            raise RefinementError(f"bad reward settings {d!r}: {err}") from err


def failed_breakdown(message: str) -> RewardBreakdown:
    """The record of an episode that produced no rollout (NaN reward)."""
    return RewardBreakdown(np.nan, np.nan, np.nan, None, ["failed"], message)


# ---------------------------------------------------------------------------------------------
# normalised parameter space
# ---------------------------------------------------------------------------------------------
@dataclass
class ParameterScaling:
    """``theta = theta0 + scale * x``; ``bounds`` (n, 2) are in theta units."""

    theta0: np.ndarray
    scale: np.ndarray
    bounds: np.ndarray

    def __post_init__(self) -> None:
        self.theta0 = np.asarray(self.theta0, dtype=float).ravel()
        self.scale = np.asarray(self.scale, dtype=float).ravel()
        self.bounds = np.asarray(self.bounds, dtype=float).reshape(-1, 2)
        n = self.theta0.size
        if self.scale.shape != (n,) or self.bounds.shape != (n, 2):
            raise RefinementError(f"scaling needs theta0 ({n},), scale ({n},), bounds ({n}, 2); got {self.scale.shape}, {self.bounds.shape}")
        if not (np.isfinite(self.theta0).all() and np.isfinite(self.scale).all() and (self.scale > 0).all()):
            raise RefinementError("scaling: theta0 must be finite and every scale finite and > 0")
        if np.isnan(self.bounds).any() or (self.bounds[:, 0] >= self.bounds[:, 1]).any():
            raise RefinementError("scaling: bounds must be ordered (lower < upper) without NaN")

    @classmethod
    def for_dmp(
        cls,
        dmp: DMP,
        position_limits: np.ndarray,
        position_unit: float = POSITION_UNIT,
        acceleration_unit: float = ACCELERATION_UNIT,
        time_unit: float = TIME_UNIT,
        max_execution_time: float | None = None,
    ) -> "ParameterScaling":
        """Scaling around the imitated ``dmp`` (see module docstring for the units and bounds) within the robot's
        ``position_limits`` (n, 2) rad;
        ``max_execution_time`` (s) replaces :data:`MAX_EXECUTION_TIME` as the upper bound of the
        execution time (e.g. the imitated one: never slower than the imitated throw)."""
        for name, v in (("position_unit", position_unit), ("acceleration_unit", acceleration_unit), ("time_unit", time_unit)):
            if not (np.isfinite(v) and v > 0):
                raise RefinementError(f"{name} must be a finite number > 0, got {v!r}")
        t_max = MAX_EXECUTION_TIME if max_execution_time is None else float(max_execution_time)
        if not (np.isfinite(t_max) and MIN_EXECUTION_TIME < t_max <= MAX_EXECUTION_TIME):
            raise RefinementError(f"max_execution_time must lie in ({MIN_EXECUTION_TIME}, {MAX_EXECUTION_TIME}] s, got {max_execution_time!r}")
        n, k = dmp.n_dims, dmp.n_weights_per_dim
        param = DMPParameterization(dmp)
        theta0 = param.to_vector()
        tau = float(np.clip(dmp.execution_time, MIN_EXECUTION_TIME, t_max))
        theta0[-1] = tau
        centers = dmp.basis.centers  # phase at each basis centre
        w_scale = np.tile(acceleration_unit * tau**2 / centers, n)
        scale = np.concatenate([np.full(2 * n, position_unit), w_scale, [time_unit]])
        limits = np.asarray(position_limits, dtype=float)
        if limits.shape != (n, 2):
            raise RefinementError(f"position_limits must have shape ({n}, 2) for the DMP's {n} joints, got {limits.shape}")
        w = theta0[2 * n : 2 * n + n * k]
        bounds = np.vstack(
            [
                limits,
                limits,
                np.column_stack([w - WEIGHT_BOUND_UNITS * w_scale, w + WEIGHT_BOUND_UNITS * w_scale]),
                [[MIN_EXECUTION_TIME, t_max]],
            ]
        )
        theta0[: 2 * n] = np.clip(theta0[: 2 * n], np.tile(limits[:, 0], 2), np.tile(limits[:, 1], 2))
        return cls(theta0, scale, bounds)

    @property
    def x_bounds(self) -> np.ndarray:
        """Bounds in the normalised space."""
        return (self.bounds - self.theta0[:, None]) / self.scale[:, None]

    def to_theta(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        return np.clip(self.theta0 + self.scale * x, self.bounds[:, 0], self.bounds[:, 1])

    def to_x(self, theta: np.ndarray) -> np.ndarray:
        theta = np.clip(np.asarray(theta, dtype=float), self.bounds[:, 0], self.bounds[:, 1])
        return (theta - self.theta0) / self.scale

    def to_dict(self) -> dict[str, Any]:
        return {"theta0": self.theta0.tolist(), "scale": self.scale.tolist(), "bounds": self.bounds.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "ParameterScaling":
        try:
            return cls(np.asarray(d["theta0"]), np.asarray(d["scale"]), np.asarray(d["bounds"]))
        except (KeyError, TypeError, ValueError) as err:
            raise RefinementError(f"bad scaling record: {err}") from err


# ---------------------------------------------------------------------------------------------
# the problem
# ---------------------------------------------------------------------------------------------
def params_key(x: np.ndarray) -> str:
    """Identifier of a candidate (its exact float values), to join episode records."""
    return hashlib.sha1(np.ascontiguousarray(np.asarray(x, dtype=float).ravel()).tobytes()).hexdigest()[:16]


class RefinementProblem:
    """Throw refinement of a template DMP towards a target, in the normalised space of :class:`ParameterScaling`.

    ``evaluate(X)`` simulates a batch of normalised candidates (rows of ``X``) with ``executor``
    (anything with ``evaluate(plans) -> list[Outcome]``) and returns one :class:`RewardBreakdown` each.
    Candidates whose DMP cannot be rolled out become failed episodes; an executor that raises fails the batch.
    """

    def __init__(
        self,
        robot: Robot,
        template: DMP,
        reward: ThrowReward | None = None,
        scaling: ParameterScaling | None = None,
        dt: float = PLAN_DT,
        retime: bool | None = None,
    ) -> None:
        if not isinstance(robot, Robot):
            raise RefinementError(f"robot must be a besdrake.robot.Robot, got {type(robot).__name__}")
        if not isinstance(template, DMP):
            raise RefinementError(f"template must be a besdrake.imitation.DMP, got {type(template).__name__}")
        if template.n_dims != robot.n_joints:
            raise RefinementError(f"the DMP has {template.n_dims} dimensions, the robot {robot.name!r} {robot.n_joints} joints")
        self.robot = robot
        self.parameterization = DMPParameterization(template, robot.joint_names)
        self.reward = reward if reward is not None else ThrowReward()
        self.scaling = scaling if scaling is not None else ParameterScaling.for_dmp(template, robot.position_limits)
        if self.scaling.theta0.size != self.parameterization.n_params:
            raise RefinementError(f"scaling has {self.scaling.theta0.size} parameters, the DMP {self.parameterization.n_params}")
        if not (np.isfinite(dt) and dt > 0):
            raise RefinementError(f"dt must be > 0 s, got {dt!r}")
        self.dt = float(dt)
        self.retime = DEFAULT_RETIME if retime is None else bool(retime)
        self.records: dict[str, RewardBreakdown] = {}

    @property
    def n_params(self) -> int:
        return self.parameterization.n_params

    @property
    def target(self) -> tuple[float, float]:
        return self.reward.target

    def theta(self, x: np.ndarray) -> np.ndarray:
        """DMP parameters of normalised candidate ``x`` (retimed when the problem retimes, see :meth:`retimed`)."""
        theta = self.scaling.to_theta(x)
        return self.retimed(theta) if self.retime else theta

    def retimed(self, theta: np.ndarray) -> np.ndarray:
        """``theta`` with its execution time stretched just enough that the plan keeps every joint's velocity and
        acceleration limit, as the embodiment mapping's temporal scaling does (:mod:`besdrake.embodiment.scaling`):
        stretching by ``k`` divides velocities by ``k`` and accelerations by ``k**2``. Never faster than ``theta``,
        never beyond the execution-time bound. A stretch is kept only when it mends the plan: what a stretch cannot
        mend (the acceleration of the DMP's final approach to its goal velocity, which a stretch does not lower) is
        left to the reward's penalty, on the plan as it was. A ``theta`` without a valid rollout is returned unchanged
        (its evaluation fails as before)."""
        theta = np.array(theta, dtype=float)
        upper = self.scaling.bounds[-1, 1]
        stretched = theta.copy()
        for round_ in range(RETIME_ROUNDS + 1):
            try:
                vel, acc = self.parameterization.motion_plan(stretched, dt=self.dt).peak_limit_ratios(self.robot.limits)
            except (DMPParameterError, PlanError, ValueError):
                return theta
            k = max(float(vel.max()), float(np.sqrt(acc.max())))
            if k <= 1.0:
                return stretched
            if not np.isfinite(k) or round_ == RETIME_ROUNDS or stretched[-1] >= upper:
                return theta
            stretched[-1] = min(upper, stretched[-1] * k * (1.0 + RETIME_MARGIN))
        return theta

    def plan(self, x: np.ndarray) -> MotionPlan:
        """Motion plan of normalised candidate ``x`` (raises DMPParameterError/PlanError for a bad one)."""
        plan = self.parameterization.motion_plan(self.theta(x), dt=self.dt)
        return plan.validate()

    def evaluate(self, X: np.ndarray, executor) -> list[RewardBreakdown]:
        X = np.atleast_2d(np.asarray(X, dtype=float))
        plans: list[MotionPlan | None] = []
        out: list[RewardBreakdown | None] = []
        for x in X:
            try:
                if not np.isfinite(x).all():
                    raise DMPParameterError("candidate contains NaN or infinite values")
                plans.append(self.plan(x))
                out.append(None)
            except (DMPParameterError, PlanError, ValueError) as err:
                plans.append(None)
                out.append(failed_breakdown(f"no motion plan: {err}"))
        todo = [i for i, p in enumerate(plans) if p is not None]
        if todo:
            outcomes = executor.evaluate([plans[i] for i in todo])
            if len(outcomes) != len(todo):
                raise RuntimeError(f"executor returned {len(outcomes)} outcomes for {len(todo)} plans")
            for i, o in zip(todo, outcomes):
                out[i] = self.reward(plans[i], o, self.robot.limits)
        return [r for r in out if r is not None]

    def batch_evaluator(self, executor, details_path: Path | None = None) -> Callable[[np.ndarray], list[float]]:
        """``evaluate_batch`` for :func:`besdrake.search.loop.run_search`; records every episode
        (in memory and, with ``details_path``, appended to a CSV keyed by :func:`params_key`)."""

        def evaluate_batch(X: np.ndarray) -> list[float]:
            results = self.evaluate(X, executor)
            rows = []
            for x, r in zip(np.atleast_2d(X), results):
                key = params_key(x)
                self.records[key] = r
                rows.append(_details_row(key, r))
            if details_path is not None:
                _append_details(details_path, rows)
            return [r.reward for r in results]

        return evaluate_batch

    def describe(self) -> dict[str, Any]:
        """JSON record of the problem (template, reward, scaling, dt): enough to rebuild it."""
        return {
            "robot": self.robot.reference,
            "template": self.parameterization.template.to_dict(),
            "reward": self.reward.to_dict(),
            "scaling": self.scaling.to_dict(),
            "dt": self.dt,
            "names": list(self.parameterization.names),
        } | ({"retime": True} if self.retime else {})

    @classmethod
    def from_description(cls, d: dict[str, Any]) -> "RefinementProblem":
        from besdrake.robot import RobotError, load_robot

        try:
            template = DMP.from_dict(d["template"])
            robot = load_robot(d["robot"])
        except (KeyError, TypeError, ValueError, RobotError) as err:
            raise RefinementError(f"bad problem record: {err}") from err
        return cls(robot, template, ThrowReward.from_dict(d["reward"]), ParameterScaling.from_dict(d["scaling"]), float(d["dt"]),
                   retime=bool(d.get("retime", False)))


_DETAIL_COLUMNS = ["key", "reward", "distance", "penalty", "touchdown_x", "touchdown_y", "flags", "message"]


def _details_row(key: str, r: RewardBreakdown) -> list[str]:
    td = r.touchdown if r.touchdown is not None else (np.nan, np.nan)
    return [key, repr(float(r.reward)), repr(float(r.distance)), repr(float(r.penalty)), repr(float(td[0])), repr(float(td[1])), ";".join(r.flags), r.message.replace("\n", " ")[:300]]


def _append_details(path: Path, rows: list[list[str]]) -> None:
    new = not path.exists() or path.stat().st_size == 0
    with open(path, "a", newline="") as handle:
        writer = csv.writer(handle)
        if new:
            writer.writerow(_DETAIL_COLUMNS)
        writer.writerows(rows)
        handle.flush()
        os.fsync(handle.fileno())


def read_details(path: Path) -> dict[str, RewardBreakdown]:
    """Episode records written during a run, by :func:`params_key` (a truncated last row is skipped)."""
    out: dict[str, RewardBreakdown] = {}
    if not path.exists():
        return out
    with open(path, newline="") as handle:
        reader = csv.reader(handle)
        header = next(reader, None)
        if header != _DETAIL_COLUMNS:
            raise RefinementError(f"{path}: not a refinement details file (columns {header})")
        for fields in reader:
            if len(fields) != len(_DETAIL_COLUMNS):
                continue
            try:
                tx, ty = float(fields[4]), float(fields[5])
                out[fields[0]] = RewardBreakdown(
                    float(fields[1]), float(fields[2]), float(fields[3]),
                    None if not (np.isfinite(tx) and np.isfinite(ty)) else (tx, ty),
                    [f for f in fields[6].split(";") if f], fields[7],
                )
            except ValueError:
                continue
    return out


# ---------------------------------------------------------------------------------------------
# start point and driver
# ---------------------------------------------------------------------------------------------
@dataclass
class RefinementResult:
    """Outcome of one refinement run (distances in m, times in s)."""

    best_theta: np.ndarray
    best_reward: float
    best_distance: float
    best_touchdown: tuple[float, float] | None
    success: bool
    episodes_to_success: int | None
    n_episodes: int
    n_failed: int
    wall_time: float
    rewards: np.ndarray
    distances: np.ndarray
    successes: np.ndarray
    penalties: np.ndarray = field(default_factory=lambda: np.zeros(0))
    resumed: bool = False
    stop_reason: str = "budget"
    #: restart attempts of a :class:`~besdrake.search.cmaes.StagnationRestartCMAES` run (finished ones), else empty
    attempts: list[dict[str, Any]] = field(default_factory=list)

    def best_so_far(self) -> np.ndarray:
        """Best target distance (m) of the throws within every limit, up to each episode (NaN before the first)."""
        valid = np.isfinite(self.distances) & (self.penalties == 0.0) if self.penalties.size == self.distances.size else np.isfinite(self.distances)
        d = np.where(valid, self.distances, np.inf)
        best = np.minimum.accumulate(d) if d.size else d
        return np.where(np.isfinite(best), best, np.nan)

    def summary(self) -> dict[str, Any]:
        return {
            "success": self.success,
            "episodes_to_success": self.episodes_to_success,
            "best_distance_m": None if not np.isfinite(self.best_distance) else self.best_distance,
            "best_distance_within_limits_m": (float(np.nanmin(self.best_so_far())) if np.isfinite(self.best_so_far()).any() else None),
            "best_reward": None if not np.isfinite(self.best_reward) else self.best_reward,
            "best_touchdown_m": None if self.best_touchdown is None else list(self.best_touchdown),
            "n_episodes": self.n_episodes,
            "n_failed": self.n_failed,
            "wall_time_s": self.wall_time,
            "resumed": self.resumed,
            "stop_reason": self.stop_reason,
            "n_restarts": len(self.attempts),
        }


def best_start(problems: Sequence[RefinementProblem], executor) -> tuple[int, RewardBreakdown]:
    """Index of the imitated throw (x = 0 of each problem) with the highest reward, and its record."""
    return rank_starts(problems, executor)[0]


def rank_starts(problems: Sequence[RefinementProblem], executor) -> list[tuple[int, RewardBreakdown]]:
    """Every imitated throw (x = 0 of each problem) with its record, best reward first (failed ones last)."""
    results = [(i, p.evaluate(np.zeros((1, p.n_params)), executor)[0]) for i, p in enumerate(problems)]
    if not any(np.isfinite(r.reward) for _, r in results):
        raise RefinementError("none of the imitated throws could be simulated")
    return sorted(results, key=lambda ir: -ir[1].reward if np.isfinite(ir[1].reward) else np.inf)


def restart_points(problem: RefinementProblem, others: Sequence[RefinementProblem]) -> np.ndarray:
    """The imitated throws of ``others`` as candidates of ``problem``'s normalised space, shape
    ``(len(others), n_params)`` (clipped to its bounds): start points of restart attempts."""
    rows = []
    for p in others:
        if p.n_params != problem.n_params:
            raise RefinementError(f"restart point with {p.n_params} parameters for a problem with {problem.n_params}")
        rows.append(problem.scaling.to_x(p.scaling.theta0))
    return np.array(rows, dtype=float).reshape(-1, problem.n_params)


def scout_start_points(problems: Sequence[RefinementProblem], ranking: Sequence[tuple[int, RewardBreakdown]],
                       n: int | None = None) -> np.ndarray | None:
    """Start points of the scouts (``refine(starts=...)``): the ``n`` best imitated throws of ``ranking`` (from
    :func:`rank_starts`; default :data:`DEFAULT_SCOUT_STARTS`) in the normalised space of the best one, the best first;
    None when ``n`` is 1 (every scout from the start throw). A throw that failed in simulation is not a start point."""
    return scout_points(problems, [i for i, r in ranking if np.isfinite(r.reward)], n)


def scout_starts_checked(n: int | None) -> int:
    """The number of scout start points, :data:`DEFAULT_SCOUT_STARTS` where None; :class:`RefinementError` unless >= 1."""
    n = DEFAULT_SCOUT_STARTS if n is None else n
    if int(n) != n or n < 1:
        raise RefinementError(f"scout starts must be an integer >= 1, got {n!r}")
    return int(n)


def scout_points(problems: Sequence[RefinementProblem], order: Sequence[int], n: int | None = None) -> np.ndarray | None:
    """:func:`scout_start_points` from ``order``: the indices of the imitated throws that could be simulated, best
    first (as ``besdrake refine`` keeps them in its start.json)."""
    n = scout_starts_checked(n)
    if n == 1:
        return None
    return restart_points(problems[order[0]], [problems[i] for i in order[:n]])


def meta_basis(problem: RefinementProblem, offset_unit: float = META_OFFSET_UNIT) -> np.ndarray:
    """Directions of the meta-parameter stage in the normalised space, shape ``(n_params, 2 n + 1)``:

    * per joint, an *offset* of the whole movement (start and goal together) by ``offset_unit`` rad per
      unit: it turns the scoop (the imitated throws start with the scoop tilted beyond its walls) and
      the direction of the throw without changing the swing's shape;
    * per joint, the *goal* (one unit of the normalised space, :data:`POSITION_UNIT` rad): the swing's amplitude;
    * the *execution time* (:data:`TIME_UNIT` s per unit).
    """
    if not (np.isfinite(offset_unit) and offset_unit > 0):
        raise RefinementError(f"offset_unit must be a finite number > 0 rad, got {offset_unit!r}")
    n = problem.parameterization.template.n_dims
    scale = problem.scaling.scale
    cols = []
    for j in range(n):
        c = np.zeros(problem.n_params)
        c[j] = offset_unit / scale[j]
        c[n + j] = offset_unit / scale[n + j]
        cols.append(c)
    for j in range(n):
        c = np.zeros(problem.n_params)
        c[n + j] = 1.0
        cols.append(c)
    c = np.zeros(problem.n_params)
    c[-1] = 1.0
    cols.append(c)
    return np.column_stack(cols)


def _search_defaults(cma_options: dict[str, Any] | None, stagnation_generations: int | None, meta_episodes: int,
                     restart_regimes: str | None = None, popsize_growth: float | None = None) -> tuple[dict[str, Any], int, str, float]:
    """The default search where a setting is None: :data:`DEFAULT_CMA_OPTIONS`, restarts after
    :data:`DEFAULT_STAGNATION_GENERATIONS` unless the meta-parameter stage is asked for (they do not combine),
    :data:`DEFAULT_RESTART_REGIMES` and :data:`DEFAULT_POPSIZE_GROWTH`."""
    cma_options = dict(DEFAULT_CMA_OPTIONS if cma_options is None else cma_options)
    if stagnation_generations is None:
        stagnation_generations = DEFAULT_STAGNATION_GENERATIONS if meta_episodes == 0 else 0
    regimes = DEFAULT_RESTART_REGIMES if restart_regimes is None else str(restart_regimes)
    if regimes not in RESTART_REGIMES:
        raise RefinementError(f"restart_regimes must be one of {RESTART_REGIMES}, got {restart_regimes!r}")
    growth = DEFAULT_POPSIZE_GROWTH if popsize_growth is None else float(popsize_growth)
    if not (np.isfinite(growth) and growth >= 1):
        raise RefinementError(f"popsize_growth must be a finite number >= 1, got {popsize_growth!r}")
    return cma_options, int(stagnation_generations), regimes, growth


def _scouting_defaults(scouts: int | None, scout_generations: int | None,
                       scout_halving: bool | None = None) -> tuple[int, int, bool]:
    """:data:`DEFAULT_SCOUTS`, :data:`DEFAULT_SCOUT_GENERATIONS` and :data:`DEFAULT_SCOUT_HALVING` where a setting is
    None, checked."""
    scouts = DEFAULT_SCOUTS if scouts is None else scouts
    scout_generations = DEFAULT_SCOUT_GENERATIONS if scout_generations is None else scout_generations
    if int(scouts) != scouts or scouts < 0 or int(scout_generations) != scout_generations or scout_generations < 1:
        raise RefinementError(f"scouts must be an integer >= 0 and scout_generations >= 1, got {scouts!r}, {scout_generations!r}")
    return int(scouts), int(scout_generations), DEFAULT_SCOUT_HALVING if scout_halving is None else bool(scout_halving)


def scouting_episodes(popsize: int = DEFAULT_POPSIZE, scouts: int | None = None, scout_generations: int | None = None,
                      scout_halving: bool | None = None) -> int:
    """Episodes the scouts take before the best goes on (none stalling early); defaults where None."""
    scouts, scout_generations, halving = _scouting_defaults(scouts, scout_generations, scout_halving)
    if scouts < 2:
        return 0
    if not halving:
        return scouts * scout_generations * int(popsize)
    total, n = 0, scouts
    while n > 1:  # a rung of n scouts, then the better half races on
        total += n * scout_generations * int(popsize)
        n = (n + 1) // 2
    return total


def make_optimizer(
    problem: RefinementProblem,
    seed: int = 0,
    sigma0: float = 1.0,
    popsize: int = DEFAULT_POPSIZE,
    x0: np.ndarray | None = None,
    *,
    meta_episodes: int = 0,
    meta_sigma: float = 1.0,
    stagnation_generations: int | None = None,
    starts: np.ndarray | None = None,
    restart_from_best: bool = True,
    stagnation_tol: float = STAGNATION_TOL,
    max_attempt_generations: int = 0,
    cma_options: dict[str, Any] | None = None,
    popsize_growth: float | None = None,
    restart_regimes: str | None = None,
    small_share: float = 1.0,
    patience: int = DEFAULT_PATIENCE,
    scouts: int | None = None,
    scout_generations: int | None = None,
    scout_halving: bool | None = None,
):
    """CMA-ES on the normalised space, started at the imitated throw (``x0 = 0``) unless ``x0`` is given.

    With ``stagnation_generations > 0`` a :class:`~besdrake.search.cmaes.StagnationRestartCMAES`: a
    CMA-ES attempt ends when its best reward improved by less than ``stagnation_tol`` (m) over that many
    generations (or after ``max_attempt_generations``), and the next attempt starts with a fresh step
    ``sigma0`` from the next row of ``starts`` (normalised candidates, e.g. :func:`restart_points`;
    default: ``x0`` only), or from the best throw so far with ``restart_from_best``. ``cma_options``:
    further options of the ``cma`` package (JSON values), e.g. ``{"CMA_diagonal": True}`` (separable CMA-ES).

    With ``meta_episodes > 0`` a :class:`~besdrake.search.cmaes.StagedCMAES`: first CMA-ES (step
    ``meta_sigma``) over the meta-parameters of :func:`meta_basis` for ``meta_episodes`` episodes, then
    CMA-ES over all parameters from the best throw so far with step ``sigma0``."""
    from besdrake.search.cmaes import CMAES, StagedCMAES

    x0 = np.zeros(problem.n_params) if x0 is None else np.asarray(x0, dtype=float)
    bounds = problem.scaling.x_bounds
    x0 = np.clip(x0, bounds[:, 0] + 1e-9, bounds[:, 1] - 1e-9)
    rng = np.random.default_rng(seed)
    cma_options, stagnation_generations, restart_regimes, popsize_growth = _search_defaults(
        cma_options, stagnation_generations, meta_episodes, restart_regimes, popsize_growth)
    scouts, scout_generations, scout_halving = _scouting_defaults(scouts, scout_generations, scout_halving)
    if stagnation_generations > 0 and meta_episodes > 0:
        raise RefinementError("stagnation restarts and the meta-parameter stage do not combine; give one of them")
    if stagnation_generations > 0:
        from besdrake.search.cmaes import StagnationRestartCMAES

        pts = x0[None, :] if starts is None else np.atleast_2d(np.asarray(starts, dtype=float))
        if pts.shape[1:] != (problem.n_params,):
            raise RefinementError(f"starts must have {problem.n_params} columns, got shape {pts.shape}")
        span = bounds[:, 1] - bounds[:, 0]
        pts = np.clip(pts, bounds[:, 0] + 1e-9 * span, bounds[:, 1] - 1e-9 * span)
        return StagnationRestartCMAES(pts, sigma0, rng, popsize=popsize, bounds=bounds, stagnation_generations=stagnation_generations,
                                      tol=stagnation_tol, max_generations=max_attempt_generations, restart_from_best=restart_from_best,
                                      cma_options=cma_options, popsize_growth=popsize_growth, regimes=restart_regimes,
                                      small_share=small_share, patience=patience, scouts=scouts,
                                      scout_generations=scout_generations, scout_halving=scout_halving)
    if meta_episodes > 0:
        return StagedCMAES(x0, meta_basis(problem), meta_sigma, sigma0, rng, subspace_evaluations=meta_episodes,
                           popsize_subspace=popsize, popsize=popsize, bounds=bounds, cma_options=cma_options)
    return CMAES(x0, sigma0, rng, popsize=popsize, bounds=bounds, cma_options=cma_options)


def refine(
    problem: RefinementProblem,
    executor,
    n_episodes: int = 2000,
    seed: int = 0,
    out_dir: str | Path | None = None,
    sigma0: float = 1.0,
    popsize: int = DEFAULT_POPSIZE,
    stop_on_success: bool = True,
    progress: Callable[[int, float, float], None] | None = None,
    optimizer=None,
    *,
    meta_episodes: int = 0,
    meta_sigma: float = 1.0,
    stagnation_generations: int | None = None,
    starts: np.ndarray | None = None,
    restart_from_best: bool = True,
    stagnation_tol: float = STAGNATION_TOL,
    max_attempt_generations: int = 0,
    cma_options: dict[str, Any] | None = None,
    popsize_growth: float | None = None,
    restart_regimes: str | None = None,
    small_share: float = 1.0,
    patience: int = DEFAULT_PATIENCE,
    scouts: int | None = None,
    scout_generations: int | None = None,
    scout_halving: bool | None = None,
) -> RefinementResult:
    """Refine ``problem`` with CMA-ES for at most ``n_episodes`` episodes (stops at the first
    generation with a success when ``stop_on_success``). With ``out_dir`` the run is resumable:
    calling again with the same folder continues it (see :mod:`besdrake.search.loop`).
    ``progress(n_episodes, best_distance, generation_wall_time)`` is called after each generation.
    ``meta_episodes``/``meta_sigma``: the meta-parameter stage of :func:`make_optimizer` (0: none)."""
    from besdrake.search.loop import run_search

    if n_episodes < 1:
        raise RefinementError(f"n_episodes must be >= 1, got {n_episodes}")
    cma_options, stagnation_generations, restart_regimes, popsize_growth = _search_defaults(
        cma_options, stagnation_generations, meta_episodes, restart_regimes, popsize_growth)
    if stagnation_generations < 0:
        raise RefinementError(f"stagnation_generations must be >= 0, got {stagnation_generations}")
    if int(patience) != patience or patience < 1:
        raise RefinementError(f"patience must be an integer >= 1, got {patience!r}")
    scouts, scout_generations, scout_halving = _scouting_defaults(scouts, scout_generations, scout_halving)
    if meta_episodes < 0 or not (np.isfinite(meta_sigma) and meta_sigma > 0):
        raise RefinementError(f"meta_episodes must be >= 0 and meta_sigma > 0, got {meta_episodes}, {meta_sigma}")
    out = None if out_dir is None else Path(out_dir)
    details_path = None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        desc_path = out / PROBLEM_FILE
        desc = problem.describe() | {"seed": int(seed), "sigma0": float(sigma0), "popsize": int(popsize)}
        if meta_episodes > 0:
            desc |= {"meta_episodes": int(meta_episodes), "meta_sigma": float(meta_sigma)}
        if stagnation_generations > 0:
            desc |= {"stagnation_generations": int(stagnation_generations), "stagnation_tol": float(stagnation_tol),
                     "max_attempt_generations": int(max_attempt_generations), "restart_from_best": bool(restart_from_best),
                     "starts": None if starts is None else np.atleast_2d(np.asarray(starts, dtype=float)).tolist()}
            if popsize_growth != 1.0:
                desc |= {"popsize_growth": float(popsize_growth)}
            if restart_regimes != "large":
                desc |= {"restart_regimes": str(restart_regimes)}
            if small_share != 1.0:
                desc |= {"small_share": float(small_share)}
            if restart_regimes == "local":
                desc |= {"patience": int(patience)}
            if scouts > 1:
                desc |= {"scouts": int(scouts), "scout_generations": int(scout_generations)}
                if scout_halving:
                    desc["scout_halving"] = True
        if cma_options:
            desc |= {"cma_options": dict(cma_options)}
        if desc_path.exists():
            try:
                old = json.loads(desc_path.read_text())
            except (OSError, json.JSONDecodeError) as err:
                raise RefinementError(f"{desc_path} is corrupt: {err}") from err
            if json.dumps(old, sort_keys=True) != json.dumps(json.loads(json.dumps(desc)), sort_keys=True):
                raise RefinementError(f"{out} holds another refinement run (different template, target, seed or settings); use another folder")
        else:
            write_json(desc_path, desc)
        details_path = out / DETAILS_FILE
        problem.records.update(read_details(details_path))
    opt = optimizer if optimizer is not None else make_optimizer(
        problem, seed, sigma0, popsize, meta_episodes=meta_episodes, meta_sigma=meta_sigma, stagnation_generations=stagnation_generations,
        starts=starts, restart_from_best=restart_from_best, stagnation_tol=stagnation_tol, max_attempt_generations=max_attempt_generations,
        cma_options=cma_options, popsize_growth=popsize_growth, restart_regimes=restart_regimes, small_share=small_share,
        patience=patience, scouts=scouts, scout_generations=scout_generations, scout_halving=scout_halving)
    t0 = time.perf_counter()
    best = [np.inf]
    last = [t0]

    def callback(info) -> bool:
        recs = [problem.records.get(params_key(x)) for x in info.candidates]
        for r in recs:
            if r is not None and np.isfinite(r.distance) and r.penalty == 0.0:
                best[0] = min(best[0], r.distance)
        now = time.perf_counter()
        if progress is not None:
            progress(info.n_evaluations, best[0], now - last[0])
        last[0] = now
        return bool(stop_on_success and any(r is not None and r.success for r in recs))

    loop = run_search(opt, problem.batch_evaluator(executor, details_path), n_evaluations=n_episodes, out_dir=out, callback=callback)
    wall = time.perf_counter() - t0
    return _result(problem, loop, wall)


def _result(problem: RefinementProblem, loop, wall: float) -> RefinementResult:
    recs = [problem.records.get(params_key(x)) for x in loop.params]
    distances = np.array([np.nan if r is None else r.distance for r in recs], dtype=float)
    successes = np.array([r is not None and r.success for r in recs], dtype=bool)
    penalties = np.array([np.nan if r is None else r.penalty for r in recs], dtype=float)
    rewards = np.asarray(loop.rewards, dtype=float)
    ok = np.flatnonzero(np.isfinite(rewards) & ~loop.failed)
    if successes.any():
        # best = closest successful throw
        idx = np.flatnonzero(successes)
        i = int(idx[np.argmin(distances[idx])])
    elif ok.size:
        i = int(ok[np.argmax(rewards[ok])])
    else:
        i = -1
    if i >= 0:
        r = recs[i]
        best_theta = problem.theta(loop.params[i])
        best_reward, best_distance = float(rewards[i]), float(distances[i])
        best_td = None if r is None else r.touchdown
    else:
        best_theta, best_reward, best_distance, best_td = problem.scaling.theta0.copy(), -np.inf, np.inf, None
    first = int(np.argmax(successes)) + 1 if successes.any() else None
    return RefinementResult(
        best_theta=best_theta, best_reward=best_reward, best_distance=best_distance, best_touchdown=best_td,
        success=bool(successes.any()), episodes_to_success=first, n_episodes=int(loop.n_evaluations),
        n_failed=int(loop.n_failed), wall_time=wall, rewards=rewards, distances=distances, successes=successes,
        penalties=penalties, resumed=bool(loop.resumed), stop_reason=loop.stop_reason,
        attempts=[dict(a) for a in getattr(loop.optimizer, "attempt_history", [])],
    )


__all__ = [
    "SUCCESS_DISTANCE", "DEFAULT_TARGET", "DEFAULT_POPSIZE", "MIN_EXECUTION_TIME", "MAX_EXECUTION_TIME", "PAPER_POPSIZE",
    "RefinementError", "RewardBreakdown", "ThrowReward", "ParameterScaling", "RefinementProblem",
    "RefinementResult", "best_start", "rank_starts", "restart_points", "scout_start_points", "scout_points", "scout_starts_checked", "scouting_episodes", "make_optimizer", "refine", "read_details", "params_key", "failed_breakdown",
]


def plot_learning_curves(results: Sequence[RefinementResult], path: str | Path) -> Path:
    """PNG of the best target distance within limits over the episodes, one line per run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for k, r in enumerate(results):
        best = r.best_so_far()
        ax.plot(np.arange(1, best.size + 1), best, label=f"run {k}")
    ax.axhline(SUCCESS_DISTANCE, color="gray", lw=1, ls="--", label="goal 0.1 m")
    ax.set_xlabel("episode")
    ax.set_ylabel("best distance within limits so far (m)")
    ax.set_yscale("log")
    ax.legend()
    fig.tight_layout()
    path = Path(path)
    _save_figure(fig, path, dpi=100)
    plt.close(fig)
    return path
