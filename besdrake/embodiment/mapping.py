"""The embodiment mapping of one demonstrated segment: hand poses -> a joint-space DMP for a robot.

Steps (paper sections 2.3.2 and 3.1.4), each in its own module:

1. synchronization frame (:mod:`~besdrake.embodiment.sync_frame`), one joint program;
2. inverse kinematics at the recording's rate in the robot's base frame (:mod:`~besdrake.embodiment.ik`);
   in both, the robot file's tool axis is kept within ``hold_cone_deg`` of vertical (the palm's axis is
   turned into that cone): the paper notes that imitation does not consider whether the tool can hold
   what it carries, and with the palm's axis alone every imitated movement of the default subjects starts
   with the tool tilted 75-119 degrees and loses its load within 0.15 s;
3. temporal scaling to the joint limits and the 0.95 s minimum (:mod:`~besdrake.embodiment.scaling`);
4. a joint-space DMP (:class:`besdrake.imitation.DMP`, 6 weights per joint) imitating the scaled
   trajectory; its rollout is checked against the limits and, if it still exceeds them, refitted
   with a longer execution time.

The result holds the parameters policy search refines (49 for a 6-joint arm with 6 weights per joint) (start, goal, weights, execution time)
and everything a report needs: residuals per pose, unreachable poses, peak joint velocities and
accelerations against the limits, timings.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from besdrake._io import write_text as _atomic_write_text
from besdrake.embodiment.ik import IKTrajectory, ik_trajectory
from besdrake.embodiment.kinematics import KinematicModel, mount_to_transform, mounted_plant, welded_plant
from besdrake.embodiment.record_mapping import HandTrajectory
from besdrake.embodiment.scaling import TemporalScaling, ease_in, temporal_scaling, toppra_duration
from besdrake.embodiment.sync_frame import SyncFrameOptions, SyncFrameResult, solve_sync_frame
from besdrake.imitation import DMP, WEIGHTS_PER_JOINT, DMPParameterization
from besdrake.plan import LimitReport, MotionPlan
from besdrake.robot import Robot


def within_cone(axes: np.ndarray, up: np.ndarray, max_angle: float) -> np.ndarray:
    """Unit ``axes`` (n, 3) turned towards ``up`` (in their common plane) where they lie more than
    ``max_angle`` rad from it; the others unchanged. Continuous in the axes, so a smooth demonstrated
    orientation stays smooth."""
    up = up / np.linalg.norm(up)
    a = axes / np.linalg.norm(axes, axis=1, keepdims=True)
    cos = a @ up
    side = a - cos[:, None] * up
    norm = np.linalg.norm(side, axis=1, keepdims=True)
    fallback = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    side = np.where(norm > 1e-9, side / np.maximum(norm, 1e-12), fallback / np.linalg.norm(fallback))
    clamped = np.cos(max_angle) * up + np.sin(max_angle) * side
    return np.where((cos < np.cos(max_angle))[:, None], clamped, a)


class ImitationError(ValueError):
    """A demonstrated segment that cannot be turned into an executable plan."""


@dataclass
class ImitationOptions:
    """Choices of the embodiment mapping."""

    sync: SyncFrameOptions = field(default_factory=SyncFrameOptions)
    smooth_window_s: float = 0.07  # low-pass of the hand poses before IK (0: off)
    ease_in_s: float = 0.05  # run-up from rest prepended at the demonstrated speed (0: off)
    n_weights_per_dim: int = WEIGHTS_PER_JOINT
    plan_dt: float = 0.002  # s between motion-plan samples
    velocity_safety: float = 0.9  # fraction of the limits the scaled trajectory may use
    max_refits: int = 8
    joint_margins: tuple[float, ...] = (0.1, 0.25)  # rad kept from the position limits, tried in turn
    refit_stretch: float = 1.1
    #: Holding constraint: the tool axis (e.g. an open tool's opening) stays within this angle (deg) of the base's
    #: vertical, in the synchronization frame and the inverse kinematics, so a load the tool carries stays in it
    #: until the movement releases it (None: the palm's demonstrated axis only, as in the paper).
    hold_cone_deg: float | None = 35.0


@dataclass
class ImitatedMovement:
    """One demonstrated segment mapped to the robot."""

    robot: Robot
    dmp: DMP
    plan: MotionPlan
    sync: SyncFrameResult
    ik: IKTrajectory
    scaling: TemporalScaling
    limits: LimitReport
    timings: dict[str, float]
    name: str = "movement"

    @property
    def parameterization(self) -> DMPParameterization:
        return DMPParameterization(self.dmp, self.robot.joint_names)

    @property
    def theta(self) -> np.ndarray:
        """The parameters: start (n), goal (n), weights (n x k), execution time (1)."""
        return self.parameterization.to_vector()

    def problems(self) -> list[str]:
        """Why the plan is not executable (empty when it is)."""
        out = [f"pose at t={p['t']:.3f} s unreachable by {1000 * p['position_residual_m']:.1f} mm" for p in self.ik.unreachable_report()]
        for i, j, step in self.ik.jumps():
            out.append(f"{self.robot.joint_names[j]} jumps by {step:.2f} rad at t={self.ik.t[i]:.3f} s (IK branch switch)")
        out += self.limits.violations()
        return out

    @property
    def executable(self) -> bool:
        """All poses reached, no jump, and the plan within every joint limit."""
        return not self.problems()

    def summary(self) -> dict[str, Any]:
        """JSON-ready report of the mapping."""
        peak_v = np.abs(self.plan.qd).max(axis=0) if self.plan.qd is not None else None
        return {
            "name": self.name,
            "executable": self.executable,
            "execution_time_s": float(self.dmp.execution_time),
            "demo_duration_s": float(self.scaling.demo_duration),
            "time_scaling_factor": float(self.scaling.factor),
            "time_scaling_limited_by": self.scaling.limiting,
            "toppra_duration_s": self.scaling.toppra_duration,
            "sync_frame_base_in_back": {"xyz_m": self.sync.mount[:3].tolist(), "yaw_pitch_roll_rad": self.sync.mount[3:].tolist()},
            "ik_max_position_residual_m": float(self.ik.position_residual.max()),
            "ik_max_angle_residual_deg": float(np.degrees(self.ik.angle_residual.max())),
            "unreachable_poses": self.ik.unreachable_report(),
            "max_joint_step_rad": self.ik.max_joint_step,
            "peak_joint_velocity_rad_s": None if peak_v is None else peak_v.tolist(),
            "velocity_limit_rad_s": self.robot.velocity_limits.tolist(),
            "limit_violations": self.limits.violations(),
            "problems": self.problems(),
            "timings_s": self.timings,
        }

    def save(self, folder: str | Path) -> Path:
        """Write ``<name>.plan.json`` (the motion plan), ``<name>.dmp.json`` and ``<name>.json`` (summary + theta)."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        self.plan.save(folder / f"{self.name}.plan.json")
        self.dmp.save(folder / f"{self.name}.dmp.json")
        data = self.summary() | {"theta": self.theta.tolist(), "theta_names": list(self.parameterization.names)}
        path = folder / f"{self.name}.json"
        _atomic_write_text(path, json.dumps(data, indent=1))
        return path


class EmbodimentMapping:
    """Maps demonstrated hand trajectories to ``robot``; builds its kinematic models once."""

    def __init__(self, robot: Robot, options: ImitationOptions | None = None) -> None:
        if not isinstance(robot, Robot):
            raise TypeError(f"EmbodimentMapping needs a Robot (besdrake.robot.load_robot), got {type(robot).__name__}")
        self.robot = robot
        self.options = options or ImitationOptions()
        self._mounted: KinematicModel | None = None
        self._welded: KinematicModel | None = None

    @property
    def mounted(self) -> KinematicModel:
        if self._mounted is None:
            self._mounted = mounted_plant(self.robot)
        return self._mounted

    @property
    def welded(self) -> KinematicModel:
        if self._welded is None:
            self._welded = welded_plant(self.robot)
        return self._welded

    def _fit_within_limits(self, t: np.ndarray, q: np.ndarray, stretch: float):
        """Fit the DMP to ``q(t)`` stretched by ``stretch``; stretch more while its rollout exceeds the
        velocity or acceleration limits (a position overshoot is not cured by slowing down)."""
        opts, robot = self.options, self.robot
        for _ in range(opts.max_refits):
            dmp = DMP(robot.n_joints, n_weights_per_dim=opts.n_weights_per_dim).fit(t * stretch, q)
            parameterization = DMPParameterization(dmp, robot.joint_names)
            plan = parameterization.motion_plan(parameterization.to_vector(), dt=opts.plan_dt)
            limits = plan.check_limits(robot.limits)
            if not (np.any(limits.velocity > 0) or np.any(limits.acceleration > 0)):
                break
            stretch *= opts.refit_stretch
        return dmp, plan, limits, stretch

    def imitate(self, hand: HandTrajectory, name: str = "movement") -> ImitatedMovement:
        """Synchronization frame, IK, temporal scaling and DMP imitation of one segment."""
        opts = self.options
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        if opts.smooth_window_s > 0:
            hand = hand.smoothed(opts.smooth_window_s)
        # A DMP may overshoot the IK path by a few hundredths of a radian: when the plan breaks
        # a position limit, frame and IK are solved again with a wider margin to the limits.
        for margin in opts.joint_margins:
            t1 = time.perf_counter()
            sync = solve_sync_frame(hand, replace(opts.sync, joint_margin=margin, hold_cone_deg=opts.hold_cone_deg), self.mounted)
            timings["sync_frame"] = timings.get("sync_frame", 0.0) + time.perf_counter() - t1
            X_BS = mount_to_transform(sync.mount).inverse()
            R = X_BS.rotation().matrix()
            p_B = hand.position @ R.T + X_BS.translation()
            axes_B = hand.palm_axis @ R.T
            if opts.hold_cone_deg is not None:
                axes_B = within_cone(axes_B, np.array([0.0, 0.0, 1.0]), np.radians(opts.hold_cone_deg))
            q_guess = np.stack([np.interp(hand.t, sync.t, sync.q[:, j]) for j in range(self.robot.n_joints)], axis=1)
            t1 = time.perf_counter()
            ik = ik_trajectory(
                self.welded, hand.t, p_B, axes_B, q_guess, position_tolerance=opts.sync.position_tolerance, joint_margin=margin
            )
            timings["inverse_kinematics"] = timings.get("inverse_kinematics", 0.0) + time.perf_counter() - t1
            t2 = time.perf_counter()
            # Peak velocities and accelerations of the DMP fitted at the demonstrated speed: the DMP
            # is what will be executed, and its derivatives are free of the IK's sample noise.
            t_demo, q_demo = ease_in(hand.t, ik.q, opts.ease_in_s)
            demo = DMP(self.robot.n_joints, n_weights_per_dim=opts.n_weights_per_dim).fit(t_demo, q_demo).open_loop(0.001)
            scaling = temporal_scaling(demo.t, demo.y, self.robot.limits, safety=opts.velocity_safety)
            timings["temporal_scaling"] = timings.get("temporal_scaling", 0.0) + time.perf_counter() - t2
            t3 = time.perf_counter()
            dmp, plan, limits, stretch = self._fit_within_limits(t_demo, q_demo, scaling.factor)
            timings["dmp_fit"] = timings.get("dmp_fit", 0.0) + time.perf_counter() - t3
            if not np.any(limits.position > 0):
                break
        t4 = time.perf_counter()
        scaling.toppra_duration = toppra_duration(
            hand.t, ik.q, self.robot.velocity_limits, self.robot.acceleration_limits, plant=self.welded.plant
        )
        timings["toppra"] = time.perf_counter() - t4
        timings["total"] = time.perf_counter() - t0
        scaling.factor = float(stretch)
        scaling.duration = float(dmp.execution_time)
        return ImitatedMovement(robot=self.robot, dmp=dmp, plan=plan, sync=sync, ik=ik, scaling=scaling, limits=limits, timings=timings, name=name)
