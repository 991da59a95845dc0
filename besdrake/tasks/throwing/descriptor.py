"""Behaviour description of a simulated throw: the 17 features the transferability surrogate uses.

The paper (section 3.1.5) describes the "type of activity" of a motion plan by 17 features computed
in simulation, "including (among others) the time of release, maximum joint accelerations and the
posture at half-time". Ours:

==========================  ====  ==========================================================
feature                     n     meaning
==========================  ====  ==========================================================
release_time                1     s; the plan's duration when the ball was never released
release_position x, y, z    3     m, world frame (ball centre)
release_velocity x, y, z    3     m/s
max_acceleration joint1..6  6     rad/s^2, largest commanded joint acceleration
posture_half joint1,2,3,5   4     rad, commanded joint angles at half the plan's duration
==========================  ====  ==========================================================

Joints 4 and 6 turn the scoop about its own axis and change the throw little, so only four
joints enter the half-time posture. Features are on different scales: users standardise them
(:func:`standardise`) before distances or a surrogate see them.
"""

from __future__ import annotations

import numpy as np

from besdrake.plan import MotionPlan

DESCRIPTOR_NAMES: tuple[str, ...] = (
    "release_time",
    "release_x",
    "release_y",
    "release_z",
    "release_vx",
    "release_vy",
    "release_vz",
    *(f"max_acceleration_joint{j}" for j in range(1, 7)),
    *(f"posture_half_joint{j}" for j in (1, 2, 3, 5)),
)
N_FEATURES = len(DESCRIPTOR_NAMES)
assert N_FEATURES == 17


def behaviour_descriptor(plan: MotionPlan, outcome) -> np.ndarray:
    """The 17 features of ``plan`` as simulated in ``outcome`` (a :class:`~besdrake.tasks.throwing.outcome.Outcome`)."""
    t = np.linspace(0.0, plan.duration, max(3, int(plan.duration / 0.005) + 1))
    qdd = plan.sample(t, derivative=2)
    half = plan.sample(np.array([0.5 * plan.duration]))[0]
    if outcome.release_time is not None and outcome.release_position is not None:
        release = [outcome.release_time, *outcome.release_position, *outcome.release_velocity]
    elif len(outcome.ball_path):
        # Never released (or failed): the ball's last simulated state stands in for the release.
        p = outcome.ball_path[-1]
        v = (outcome.ball_path[-1] - outcome.ball_path[-2]) / max(outcome.ball_t[-1] - outcome.ball_t[-2], 1e-9) if len(outcome.ball_path) > 1 else np.zeros(3)
        release = [plan.duration, *p, *v]
    else:
        release = [plan.duration, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    return np.array([*release, *np.abs(qdd).max(axis=0), *half[[0, 1, 2, 4]]], dtype=float)


def standardise(features: np.ndarray, reference: np.ndarray | None = None) -> np.ndarray:
    """Features scaled to zero mean and unit spread of ``reference`` (default: themselves)."""
    ref = features if reference is None else reference
    mean = ref.mean(axis=0)
    scale = ref.std(axis=0)
    scale[scale < 1e-9] = 1.0
    return (features - mean) / scale
