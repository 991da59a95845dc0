"""Designed diagnosis experiments for pick-and-place: the scripted pick (:func:`~besdrake.tasks.pick_and_place.
scripted.scripted_plan`) of the perceived box, put down at place targets spread around the scene's place and carried
at different speeds, some plans repeated (their scatter is the noise the causes are tested against).

Spread places turn the arm by different angles between the shelf and the table, so a box that stands off along the
approach ends up displaced in different world directions, while an encoder offset moves the tool by an amount that
depends on the pose; faster carries load the grasp more (a slippery pad or a heavy box slips sooner) and show a lag
in the tracking errors. Every plan is checked against the robot's joint limits (the safety gate's check).
"""

from __future__ import annotations

from dataclasses import fields, replace

import numpy as np

from besdrake.plan import MotionPlan
from besdrake.robot import JointLimits
from besdrake.tasks.pick_and_place.scripted import IKError, ScriptTiming, scripted_plan

#: Place targets: offsets (m, world x and y) drawn uniformly within this of the scene's place.
PLACE_SPREAD = 0.06
#: Speeds: every segment's shortest duration times a factor drawn from this range (segments the limits stretch stay
#: stretched).
TIME_SCALE = (0.8, 1.4)


def pick_plan(rollout, dx: float = 0.0, dy: float = 0.0, time_scale: float = 1.0) -> MotionPlan:
    """The scripted pick of ``rollout``'s perceived box, put down (dx, dy) m from its place, with every segment's
    duration times ``time_scale``."""
    from besdrake.sim.diagram import base_transform

    base = ScriptTiming()
    timing = replace(base, **{f.name: getattr(base, f.name) * time_scale for f in fields(base)})
    place = rollout.place_target + np.array([dx, dy, 0.0])
    p = scripted_plan(rollout.robot, base_transform(rollout.scenario), rollout.box_start, 2 * rollout.h.box_half_size[2], place, timing)
    p.meta.update(generator="pick_plan", place_dx=float(dx), place_dy=float(dy), time_scale=float(time_scale))
    return p


def _draw(rollout, rng: np.random.Generator, limits: JointLimits | None, tries: int = 10) -> MotionPlan:
    for _ in range(tries):
        dx, dy = rng.uniform(-PLACE_SPREAD, PLACE_SPREAD, 2)
        try:
            p = pick_plan(rollout, float(dx), float(dy), float(rng.uniform(*TIME_SCALE)))
        except IKError:
            continue
        if limits is None or p.check_limits(limits).ok:
            return p
    return pick_plan(rollout)


def diagnosis_plans(n: int = 12, repeats: int = 4, seed: int = 0, limits: JointLimits | None = None,
                    scenario: str = "pick_and_place", rollout=None) -> list[MotionPlan]:
    """``n`` plans in random order: ``n - repeats`` distinct picks (the first at the scene's own place and speed, the
    others drawn: place within :data:`PLACE_SPREAD`, speed factor in :data:`TIME_SCALE`) and ``repeats`` of them run a
    second time. Seeded with ``numpy.random.default_rng(seed)``. ``rollout``: a
    :class:`~besdrake.tasks.pick_and_place.rollout.PickPlaceRollout` of the scene (default: ``scenario``'s, built in
    this process)."""
    if n < 2 or not (0 <= repeats <= n // 2):
        raise ValueError(f"diagnosis_plans: need n >= 2 and 0 <= repeats <= n/2, got n={n}, repeats={repeats}")
    if rollout is None:
        from besdrake.sim.rollout import shared_rollout

        rollout = shared_rollout(scenario)
    rng = np.random.default_rng(seed)
    k = n - repeats
    plans = [pick_plan(rollout)] + [_draw(rollout, rng, limits) for _ in range(k - 1)]
    for i, p in enumerate(plans):
        p.meta["name"] = f"pick_{i:02d}"
    rep = rng.choice(k, size=repeats, replace=False)
    allp = plans + [plans[int(i)] for i in rep]
    return [allp[int(i)] for i in rng.permutation(len(allp))]


def sample_plans(limits: JointLimits, n: int = 6, seed: int = 0, scenario: str = "pick_and_place") -> list[MotionPlan]:
    """Distinct picks within the robot's ``limits`` (the plan sample of the structural identifiability)."""
    return diagnosis_plans(n, 0, seed=seed, limits=limits, scenario=scenario)


__all__ = ["pick_plan", "diagnosis_plans", "sample_plans", "PLACE_SPREAD", "TIME_SCALE"]
