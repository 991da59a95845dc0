"""The virtual pick-and-place lab: the pick-and-place simulation plus hidden effects plus a real lab's measurement
process, behind the same :class:`~besdrake.transfer.lab.Lab` interface, log and safety gate as every lab.

Configured by a YAML file (:mod:`besdrake.tasks.pick_and_place.lab_config`). How trial ``k`` runs (every random
number from ``numpy.random.default_rng([seed, k])``, drawn in a fixed order, so trial ``k`` measures the same
whenever it is re-run, which makes resuming a log safe):

1. **The box on the shelf.** The planner knows the scenario's (perceived) box pose; the box stands at that pose plus
   the hidden ``box_pose_offset`` plus this trial's placement scatter (N(0, placement_sd^2) in x and y,
   N(0, placement_yaw_sd^2) in yaw), with the hidden ``box_mass`` and ``pad_friction`` (and any further effect the
   config names): the registry's effects (:mod:`besdrake.tasks.pick_and_place.effects`), the same the diagnosis
   searches over (:meth:`PickPlaceLab.hidden_effects`).
2. **Simulation** of the plan and its gripper command
   (:meth:`~besdrake.tasks.pick_and_place.rollout.PickPlaceRollout.rollout`).
3. **Camera.** The box's final pose is measured with N(0, pose_noise_sd^2) per axis on its position and
   N(0, angle_noise_sd^2) per axis on its orientation (a small rotation in its own frame); place error, tilt, "on the
   table" come from the measured pose; the box's highest rise and its slip in the gripper with N(0, pose_noise_sd^2).
4. **Judgement** as the simulation judges (:func:`~besdrake.tasks.pick_and_place.outcome.score`), from the measured
   values: lifted, held, upright, placed within ``place_tolerance``, no arm-fixture contact, limits kept.
5. **Encoders.** Commanded and measured arm joints at ``joint_rate_hz`` with N(0, encoder_noise_sd^2), summarised per
   joint (largest and RMS tracking error).

A plan beyond a joint position, velocity or acceleration limit (a lab without a
:class:`~besdrake.transfer.lab.SafetyGate` in front) is not run: the robot's drives stop it (flags
``joint_limit_exceeded``, ``aborted``); so is a measured joint beyond a position limit, or a failed simulation
(``aborted``, nothing measured but the encoders).
"""

from __future__ import annotations

import dataclasses
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from besdrake.plan import MotionPlan, PlanError
from besdrake.tasks.pick_and_place.lab_config import (
    PickPlaceLabConfig,
    load_pick_place_lab_config,
    parse_pick_place_lab_config,
)
from besdrake.tasks.pick_and_place.measurement import PickPlaceMeasurement
from besdrake.tasks.pick_and_place.outcome import FLAG_NAMES, PickPlaceOutcome, score
from besdrake.transfer.lab import TrialCounter


@dataclasses.dataclass(frozen=True)
class TrialDraws:
    """The random numbers of one trial (in draw order)."""

    placement: np.ndarray    # (3,) dx m, dy m, dyaw rad (world)
    position_noise: np.ndarray  # (3,) m
    angle_noise: np.ndarray  # (3,) rad
    lift_noise: float
    slip_noise: float

    @classmethod
    def draw(cls, rng: np.random.Generator, noise) -> "TrialDraws":
        sd = np.array([noise.placement_sd, noise.placement_sd, noise.placement_yaw_sd])
        return cls(rng.normal(0.0, 1.0, 3) * sd, rng.normal(0.0, noise.pose_noise_sd, 3),
                   rng.normal(0.0, noise.angle_noise_sd, 3), float(rng.normal(0.0, noise.pose_noise_sd)),
                   float(rng.normal(0.0, noise.pose_noise_sd)))


class PickPlaceLab(TrialCounter):
    """A simulated pick-and-place lab (module docstring). ``PickPlaceLab(config)`` with a
    :class:`PickPlaceLabConfig`, a config mapping or a lab YAML path / name; the Diagram is built on first use, or
    ``rollout`` (a :class:`~besdrake.tasks.pick_and_place.rollout.PickPlaceRollout` of the same scenario and robot,
    e.g. another lab's ``rollout``) is reused: labs that differ in effects or noise share one Diagram."""

    measurement_type = PickPlaceMeasurement

    def __init__(self, config: PickPlaceLabConfig | dict | str | Path, rollout=None) -> None:
        if isinstance(config, dict):
            config = parse_pick_place_lab_config(config)
        self.config = config if isinstance(config, PickPlaceLabConfig) else load_pick_place_lab_config(config)
        self.name = self.config.name
        self._rollout = rollout
        self._scenario = None
        if rollout is not None:
            mine = self.scenario
            if (rollout.scenario.name, rollout.robot.name) != (mine.name, mine.robot.name):
                raise ValueError(f"the rollout simulates {rollout.scenario.name!r} on {rollout.robot.name!r}, the lab "
                                 f"{mine.name!r} on {mine.robot.name!r}")
        self._pose = None if self.config.home_pose is None else np.array(self.config.home_pose, dtype=float)

    @property
    def scenario(self):
        """The lab's scenario with its robot (the simulation as designed: the box where perceived)."""
        if self._scenario is None:
            self._scenario = self.config.load_scenario()
        return self._scenario

    @property
    def robot(self):
        """The lab's robot (its limits are the safety gate's)."""
        return self.scenario.robot

    @property
    def rollout(self):
        """The (lazily built) simulation."""
        if self._rollout is None:
            from besdrake.tasks.pick_and_place.rollout import PickPlaceRollout

            self._rollout = PickPlaceRollout(self.scenario)
        return self._rollout

    def current_pose(self) -> np.ndarray | None:
        """Where the arm stands: the config's ``home_pose``, then the last plan's end pose; None without a home pose."""
        return None if self._pose is None else self._pose.copy()

    def description(self) -> dict[str, Any]:
        """Public facts for a log (no hidden truth): name, scenario, robot, sensors, the perceived box pose, the place."""
        c = self.config
        return {
            "name": c.name, "kind": "virtual", "task": "pick_and_place", "description": c.description,
            "scenario": Path(c.scenario).stem if str(c.scenario).endswith((".yaml", ".yml")) else c.scenario,
            "robot": self.robot.reference if hasattr(self.robot, "reference") else self.robot.name,
            "sensors": c.noise.sensors(), "record_joints": c.record_joints,
            "box_perceived_m": self.rollout.box_start.tolist(), "place_target_m": self.rollout.place_target.tolist(),
        }

    def hidden_effects(self) -> dict[str, dict[str, float]]:
        """The hidden truth as the registry's effects (what the diagnosis searches over): the box pose offset, mass and
        pad friction of :mod:`besdrake.tasks.pick_and_place.effects` and any further effect the config names."""
        return self.config.effects.registry(self.rollout.box_mass, self.rollout.pad_friction)

    def box_offset(self, placement: np.ndarray) -> np.ndarray:
        """This trial's placement scatter (dx, dy, yaw; world) in the shelf's box_start frame (the rollout's
        ``box_offset``; the hidden offset comes on top, as the ``box_pose_offset`` effect)."""
        R = self.rollout.h.box_start.rotation().matrix()
        local = R.T @ np.array([placement[0], placement[1], 0.0])
        return np.array([local[0], local[1], placement[2]])

    def execute(self, plan: MotionPlan, trial: int | None = None) -> PickPlaceMeasurement:
        """Run ``plan`` (its gripper command in ``meta["gripper"]``) as trial ``trial`` (default: the next) and measure it."""
        if not isinstance(plan, MotionPlan):
            raise TypeError(f"PickPlaceLab.execute needs a MotionPlan, got {type(plan).__name__}")
        trial = self.next_trial(trial)
        c = self.config
        rng = np.random.default_rng([c.seed, trial])
        draws = TrialDraws.draw(rng, c.noise)
        meta = {"lab": c.name, "plan_name": str(plan.meta.get("name", plan.meta.get("script", ""))),
                "executed_at": datetime.now(timezone.utc).isoformat(timespec="seconds"), "joint_rate_hz": c.noise.joint_rate_hz}

        def aborted(message: str, **flags) -> PickPlaceMeasurement:
            return PickPlaceMeasurement(trial=trial, plan=plan, flags={**flags, "aborted": True}, message=message, meta=meta)

        try:
            over = plan.check_limits(self.robot.limits).violations()
        except PlanError as err:
            return aborted(f"aborted: malformed plan: {err}")
        if over:
            return aborted("aborted: the plan drove a joint beyond its limits and the robot switched itself off: " + "; ".join(over),
                           joint_limit_exceeded=True)
        try:
            out = self.rollout.rollout(plan, effects=self.hidden_effects(), limits="flag", box_offset=self.box_offset(draws.placement))
        except PlanError as err:
            return aborted(f"aborted: malformed plan: {err}")
        if self._pose is not None:
            self._pose = np.array(plan.q[-1], dtype=float)
        encoders = self._encoders(plan, out, rng) if c.record_joints and out.t.size else None
        return self._measure(trial, plan, out, draws, encoders, meta)

    def _measure(self, trial: int, plan: MotionPlan, out: PickPlaceOutcome, d: TrialDraws, encoders, meta) -> PickPlaceMeasurement:
        """The measurement of a simulated trial: camera, judgement, encoder summary."""
        joints: dict[str, Any] = {}
        if encoders is not None:
            jt, q_cmd, q_meas = encoders
            err = q_meas - q_cmd
            joints = {"joint_t": jt, "q_commanded": q_cmd, "q_measured": q_meas,
                      "tracking_max": np.max(np.abs(err), axis=0), "tracking_rms": np.sqrt(np.mean(err ** 2, axis=0))}
        target = self.rollout.place_target
        if out.flags.get("sim_failed") or not out.limits_kept or not np.all(np.isfinite(out.box_position)):
            why = out.message if out.flags.get("sim_failed") else "a joint went beyond its position limit and the robot switched itself off"
            flags = {"joint_limit_exceeded": True} if not out.limits_kept else {}
            return PickPlaceMeasurement(trial=trial, plan=plan, flags={**flags, "aborted": True}, message=f"aborted: {why}",
                                        meta=meta, place_target=target, **joints)
        judged, pose = self._camera(out, d, target)
        flags = {k: True for k, v in judged.flags.items() if v}
        return PickPlaceMeasurement(
            trial=trial, plan=plan, flags=flags, message=judged.message, meta=meta, success=judged.success,
            grasped=judged.grasped, lifted=judged.lifted, held=judged.held, upright=judged.upright, on_table=judged.on_table,
            place_error=judged.place_error, tilt=judged.tilt, box_pose=pose, lift=judged_lift(out, d, self.rollout),
            slip=judged.max_slip if judged.lifted else None, collision=out.collision, place_target=target, **joints,
        )

    def _camera(self, out: PickPlaceOutcome, d: TrialDraws, target: np.ndarray) -> tuple[PickPlaceOutcome, np.ndarray]:
        """The outcome re-judged from measured values, and the measured box pose (x, y, z, roll, pitch, yaw)."""
        from pydrake.common.eigen_geometry import Quaternion
        from pydrake.math import RollPitchYaw, RotationMatrix

        crit = self.rollout.criteria
        R = RotationMatrix(Quaternion(out.box_quaternion)).multiply(RotationMatrix(RollPitchYaw(d.angle_noise)))
        position = out.box_position + d.position_noise
        tilt = float(np.arccos(np.clip(R.matrix()[2, 2], -1.0, 1.0)))
        lift = judged_lift(out, d, self.rollout)
        slip = max(out.max_slip + d.slip_noise, 0.0)
        flags = {k: False for k in FLAG_NAMES}
        flags["dropped"] = bool(position[2] < target[2] - crit.rest_tolerance)
        judged = dataclasses.replace(
            out, flags=flags, message="", box_position=position, tilt=tilt, upright=tilt <= crit.upright_tolerance,
            place_error=float(np.linalg.norm(position[:2] - target[:2])),
            on_table=bool(abs(position[2] - target[2]) <= crit.rest_tolerance),
            lifted=lift >= crit.lift_clearance, max_slip=slip,
            held=bool(lift >= crit.lift_clearance and slip <= crit.slip_tolerance),
        )
        score(judged, target, crit)
        return judged, np.r_[position, RollPitchYaw(R).vector()]

    def _encoders(self, plan: MotionPlan, out: PickPlaceOutcome, rng: np.random.Generator):
        """Commanded and measured arm joints at ``joint_rate_hz`` (from the plan start to the simulation's end)."""
        rate = self.config.noise.joint_rate_hz
        jt = np.arange(0, int(np.floor(out.t[-1] * rate + 1e-9)) + 1) / rate
        q = np.column_stack([np.interp(jt, out.t, out.q_arm[:, i]) for i in range(out.q_arm.shape[1])])
        return jt, plan.sample(jt), q + rng.normal(0.0, self.config.noise.encoder_noise_sd, q.shape)


def judged_lift(out: PickPlaceOutcome, d: TrialDraws, rollout) -> float:
    """Measured highest rise (m) of the box's bottom above its start on the shelf."""
    if out.box_path.size == 0:
        return d.lift_noise
    return float(np.max(out.box_path[:, 2]) - rollout.box_start[2] + d.lift_noise)


__all__ = ["PickPlaceLab", "TrialDraws"]
