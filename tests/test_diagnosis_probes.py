"""The tilt probe of the diagnosis experiment shows the ball-scoop friction that a throw hides."""

from __future__ import annotations

import numpy as np

from besdrake.tasks.throwing.diagnosis.design import PROBES, tilt_probe
from besdrake.sim import Rollout
from besdrake.tasks.throwing.throws import default_throw


def _release(roll: Rollout, plan, mu: float | None = None, placement=None):
    eff = {} if mu is None else {"scoop_friction": {"mu_static": mu, "mu_dynamic": 0.8 * mu}}
    if placement is not None:
        eff["ball_placement"] = {"x": placement[0], "y": placement[1]}
    o = roll.rollout(plan, effects=eff, limits="flag")
    assert o.release_velocity is not None and o.touchdown is not None and not any(o.flags.values()), o.flags
    return np.asarray(o.release_velocity), float(o.release_time), np.asarray(o.touchdown)


def test_a_slippery_scoop_moves_the_tilt_probe_but_hardly_the_throw():
    roll = Rollout("nominal")
    yaw, wrist, arm, tt = PROBES[0]
    probe = tilt_probe(yaw=yaw, wrist=wrist, arm=arm, tilt_time=tt)
    v0, t0, td0 = _release(roll, probe)
    assert td0[0] > 0.5  # the probe lands in front of the robot, inside the capture volume
    v1, t1, _ = _release(roll, probe, mu=0.25)
    # Sliding instead of rolling down the funnel wall: the ball leaves earlier and faster.
    assert t1 < t0 - 0.002 and np.linalg.norm(v1) > np.linalg.norm(v0) + 0.02
    # The ball settles in the funnel before it rolls, so its start in the scoop does not matter for the probe.
    vp, tp, _ = _release(roll, probe, placement=(0.003, -0.003))
    assert np.linalg.norm(vp - v0) < 0.005 and abs(tp - t0) < 0.002
    # The default throw catapults the ball out along the wall normal: friction hardly shows.
    throw = default_throw(0.35)
    w0, _, _ = _release(roll, throw)
    w1, _, _ = _release(roll, throw, mu=0.25)
    assert np.linalg.norm(w1 - w0) < 0.3 * np.linalg.norm(v1 - v0)
