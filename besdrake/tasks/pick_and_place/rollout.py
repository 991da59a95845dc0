"""The pick-and-place black box: ``PickPlaceRollout().rollout(plan) -> PickPlaceOutcome``.

Built once (about 1 s), then every call resets the Context (``SetTimeStateAndParametersFrom``), applies the
per-rollout box changes (friction, mass, start offset), swaps the arm plan and the gripper command into their
``TrajectorySource``\\ s (``UpdateTrajectory``), puts the arm at the plan's start (at the static equilibrium of its
servos), the gripper at its first command and the box at rest on the shelf, and simulates the plan plus
``criteria.tail`` s in chunks of ``check_interval``, checking between chunks for arm-fixture contacts, a box on
the floor (stop: dropped) and a diverging state (stop: ``sim_failed``). The box path, its pose in the gripper while
held and its final pose are read from the state log. Nothing here raises for simulation trouble: a solver error
or a blow-up is a flagged outcome. A malformed plan raises :class:`~besdrake.plan.PlanError`.
"""

from __future__ import annotations

import numpy as np

from besdrake.plan import MotionPlan, PlanError
from besdrake.sim.scenario import Scenario, load_scenario
from besdrake.tasks.pick_and_place.diagram import PickPlaceHandles, build_pick_place_diagram
from besdrake.tasks.pick_and_place.gripper import GripperCommand
from besdrake.tasks.pick_and_place.outcome import PickPlaceCriteria, PickPlaceOutcome, score

#: Measured joint angles may pass a position limit by this much (rad) before the flag is raised.
LIMIT_TOLERANCE = 0.01
#: A box faster than this (m/s), or a non-finite state, is a diverged simulation.
DIVERGENCE_SPEED = 20.0
#: After the gripper command has closed, the fingers settle for this long (s) before they are checked; fingers held
#: open by more than GRASP_GAP (m, per joint) beyond the command have closed on something.
GRASP_SETTLE, GRASP_GAP = 0.1, 0.002
#: Sampling period (s) of the gravity feed-forward along the plan.
FEEDFORWARD_PERIOD = 0.02


class PickPlaceRollout:
    """One Diagram reused for many rollouts of the pick-and-place scenario."""

    def __init__(self, scenario: Scenario | str = "pick_and_place", criteria: PickPlaceCriteria | None = None,
                 meshcat=None, check_interval: float = 0.02) -> None:
        from pydrake.systems.analysis import Simulator

        self.scenario = load_scenario(scenario) if not isinstance(scenario, Scenario) else scenario
        self.robot = self.scenario.robot
        self.criteria = criteria or PickPlaceCriteria()
        self.check_interval = check_interval
        self.h: PickPlaceHandles = build_pick_place_diagram(self.scenario, meshcat=meshcat)
        self.simulator = Simulator(self.h.diagram)
        self.context = self.simulator.get_mutable_context()
        self.default_context = self.h.diagram.CreateDefaultContext()
        self.plant_context = self.h.plant.GetMyMutableContextFromRoot(self.context)
        self.sg_context = self.h.scene_graph.GetMyMutableContextFromRoot(self.context)
        self.log = self.h.state_logger.FindMutableLog(self.context)
        self._scratch = self.h.plant.CreateDefaultContext()
        self._robot_geoms = set(self.h.robot_geometries)
        self._fixture_geoms = set(self.h.fixture_geometries)
        self._box_q = self.h.box_body.floating_positions_start()
        self._box_v = self.h.plant.num_positions() + self.h.box_body.floating_velocities_start_in_v()
        self._rest_height = self._box_rest_height()
        #: The box model's mass (kg) and the finger pads' friction coefficient as modelled (what the ``box_mass`` and
        #: ``pad_friction`` effects change).
        self.box_mass = float(self.h.box_body.get_mass(self.h.plant.CreateDefaultContext()))
        self.pad_friction = self._pad_friction()

    @property
    def place_target(self) -> np.ndarray:
        """Where the box's bottom centre is to stand on the table (m, world)."""
        return self.h.place_target.translation().copy()

    @property
    def box_start(self) -> np.ndarray:
        """Where the box's bottom centre stands on the shelf at the start (m, world)."""
        return self.h.box_start.translation().copy()

    # ------------------------------------------------------------------ setup
    def _box_rest_height(self) -> float:
        """Height (m) of the box's origin above the board it rests on: the lowest point of its collision shapes."""
        from pydrake.geometry import Box, Sphere

        inspector = self.h.scene_graph.model_inspector()
        low = 0.0
        for g in self.h.box_geometries:
            shape, z = inspector.GetShape(g), inspector.GetPoseInFrame(g).translation()[2]
            if isinstance(shape, Sphere):
                low = min(low, z - shape.radius())
            elif isinstance(shape, Box):
                low = min(low, z - shape.height() / 2)
        return -low

    def _set_box_friction(self, mu: float, geometries=None) -> None:
        """Friction coefficient ``mu`` (static and dynamic) of the box's collision geometries (or of ``geometries``)."""
        from pydrake.geometry import ProximityProperties, RoleAssign
        from pydrake.multibody.plant import CoulombFriction

        inspector = self.h.scene_graph.model_inspector()
        for gid in self.h.box_geometries if geometries is None else geometries:
            props = ProximityProperties(inspector.GetProximityProperties(gid))
            props.UpdateProperty("material", "coulomb_friction", CoulombFriction(mu, mu))
            self.h.scene_graph.AssignRole(self.sg_context, self.h.plant.get_source_id(), gid, props, RoleAssign.kReplace)

    def _gravity_feedforward(self, plan: MotionPlan, grip: GripperCommand, lead: float):
        """The arm's gravity torques along the plan (every ``FEEDFORWARD_PERIOD`` s) as a first-order-hold trajectory
        of the actuation input (zero for the gripper)."""
        from pydrake.trajectories import PiecewisePolynomial

        h, plant = self.h, self.h.plant
        ts = np.unique(np.r_[np.arange(0.0, plan.duration, FEEDFORWARD_PERIOD), plan.duration])
        q = plant.GetPositions(self._scratch)
        u = np.zeros((len(h.arm_rows) + len(h.gripper_joint_q), len(ts)))
        for k, (qa, qg) in enumerate(zip(plan.sample(ts), grip.joint_positions(self.robot, grip.sample(ts)))):
            q[h.arm_q], q[h.gripper_joint_q], q[h.coupled_q] = qa, qg, qg[0]
            plant.SetPositions(self._scratch, q)
            u[h.arm_rows, k] = -plant.CalcGravityGeneralizedForces(self._scratch)[h.arm_v]
        if len(ts) == 1:
            return PiecewisePolynomial(u[:, :1])
        return PiecewisePolynomial.FirstOrderHold(ts - lead, u)

    def _place_robot(self, q0: np.ndarray, grip0: np.ndarray) -> None:
        """Arm at ``q0`` (held there by the servos with the gravity feed-forward), gripper at ``grip0``, at rest."""
        h, plant = self.h, self.h.plant
        q = plant.GetPositions(self.plant_context)
        q[h.arm_q], q[h.gripper_joint_q], q[h.coupled_q] = q0, grip0, grip0[0]
        plant.SetPositions(self.plant_context, q)

    def _place_box(self, offset: np.ndarray | None) -> None:
        """The box at rest on the shelf at its perceived start moved by ``offset`` (dx m, dy m, dyaw rad; world frame)."""
        from pydrake.math import RigidTransform, RollPitchYaw

        dx, dy, yaw = (0.0, 0.0, 0.0) if offset is None else (float(v) for v in offset)
        local = self.h.box_start.rotation().matrix().T @ np.array([dx, dy, 0.0])
        X = self.h.box_start.multiply(RigidTransform(RollPitchYaw(0, 0, yaw), [local[0], local[1], self._rest_height + 1e-4]))
        self.h.plant.SetFreeBodyPose(self.plant_context, self.h.box_body, X)

    def _pad_friction(self) -> float:
        """The finger pads' (static) friction coefficient as modelled (1.0 where the model names none)."""
        inspector = self.h.scene_graph.model_inspector()
        for gid in self._finger_geometries():
            props = inspector.GetProximityProperties(gid)
            if props is not None and props.HasProperty("material", "coulomb_friction"):
                return float(props.GetProperty("material", "coulomb_friction").static_friction())
        return 1.0

    def _finger_geometries(self) -> list:
        """Collision geometries of the gripper's fingers (the bodies its joints move: their pads)."""
        h, g = self.h, self.robot.end_effector.gripper
        bodies = [h.plant.GetJointByName(j, h.robot_instance).child_body() for j in (*g.joints, *g.coupled)]
        return [gid for b in bodies for gid in h.plant.GetCollisionGeometriesForBody(b)]

    def _reset(self, plan: MotionPlan, grip: GripperCommand, effects: dict, box_friction) -> "PickPlaceSetup":
        """Reset the Context, apply the registry ``effects`` (completed) and the legacy box friction, swap the plan
        (as the effects changed it) in and place the arm, gripper and box; returns the effects' setup."""
        from besdrake.sim.effects import apply_effects
        from besdrake.tasks.pick_and_place.effects import PickPlaceSetup

        self.context.SetTimeStateAndParametersFrom(self.default_context)
        setup = PickPlaceSetup(plan=plan, handles=self.h, context=self.context, plant_context=self.plant_context,
                               scene_graph_context=self.sg_context)
        apply_effects(setup, effects)
        if box_friction is not None:
            self._set_box_friction(float(box_friction))
        if setup.pad_friction_scale != 1.0:
            self._set_box_friction(self.pad_friction * setup.pad_friction_scale, self._finger_geometries())
        if setup.box_mass_delta != 0.0:
            self.h.box_body.SetMass(self.plant_context, max(self.box_mass + setup.box_mass_delta, 1e-3))
        plan = setup.plan
        lead = self.scenario.time_step  # the implicit PD acts on the end of the step: lead the reference by one step
        self.h.arm_source.UpdateTrajectory(plan.trajectory(time_shift=-lead))
        self.h.gripper_source.UpdateTrajectory(grip.trajectory(self.robot, time_shift=-lead))
        self.h.feedforward_source.UpdateTrajectory(self._gravity_feedforward(plan, grip, lead))
        self._place_robot(plan.q[0], grip.joint_positions(self.robot, grip.width[:1])[0])
        self._place_box(setup.box_offset)
        self.log.Clear()
        return setup

    # ------------------------------------------------------------------ checks while simulating
    def _fixture_contact(self) -> str:
        """"<robot geometry> / <fixture geometry>" for a robot-fixture contact now, else ""."""
        contacts = self.h.plant.get_contact_results_output_port().Eval(self.plant_context)
        for i in range(contacts.num_point_pair_contacts()):
            pair = contacts.point_pair_contact_info(i).point_pair()
            a, b = pair.id_A, pair.id_B
            if (a in self._robot_geoms and b in self._fixture_geoms) or (b in self._robot_geoms and a in self._fixture_geoms):
                return f"{self._geometry_name(a)} / {self._geometry_name(b)}"
        return ""

    def _geometry_name(self, gid) -> str:
        """"<body>:<geometry>" (URDF collision shapes are often unnamed: the body says where)."""
        inspector = self.h.scene_graph.model_inspector()
        body = self.h.plant.GetBodyFromFrameId(inspector.GetFrameId(gid))
        return f"{body.name()}:{inspector.GetName(gid).split('::')[-1]}"

    def _simulate(self, t_end: float, out: PickPlaceOutcome) -> None:
        """Advance to ``t_end`` in chunks; record the first arm-fixture contact; stop early on the floor or a blow-up."""
        floor_z = 0.5 * self._rest_height
        t = 0.0
        try:
            self.simulator.Initialize()
            while t < t_end - 1e-9:
                t = min(t + self.check_interval, t_end)
                self.simulator.AdvanceTo(t)
                x = self.h.plant.GetPositionsAndVelocities(self.plant_context)
                if not np.all(np.isfinite(x)) or np.linalg.norm(x[self._box_v + 3:self._box_v + 6]) > DIVERGENCE_SPEED:
                    out.flags["sim_failed"], out.message = True, f"simulation diverged at t={t:.3f} s"
                    break
                if not out.arm_fixture_collision:
                    pair = self._fixture_contact()
                    if pair:
                        out.arm_fixture_collision, out.collision = True, f"{pair} at {t:.2f} s"
                if x[self._box_q + 6] < floor_z:
                    break  # the box lies on the floor: nothing more to see
        except RuntimeError as err:
            out.flags["sim_failed"] = True
            out.message = f"simulation failed at t={self.context.get_time():.3f} s: {str(err).splitlines()[0] if str(err) else err}"
        out.sim_time = float(self.context.get_time())

    # ------------------------------------------------------------------ main
    def rollout(self, plan: MotionPlan, effects: dict | None = None, limits: str = "flag", box_friction: float | None = None,
                box_mass: float | None = None, box_offset: np.ndarray | None = None,
                pad_friction: float | None = None) -> PickPlaceOutcome:
        """Simulate ``plan`` (arm joints; gripper command in ``plan.meta["gripper"]``) with the registry's ``effects``
        ``{name: {param: value}}`` (on top of the scenario's; those the task lists, :attr:`PickAndPlaceTask.effects`:
        :mod:`besdrake.tasks.pick_and_place.effects` and the plan effects ``joint_offset``, ``actuator_lag``, and a user's
        plugin effects; another task's or a robot effect it does not list, e.g. ``base_offset``, is an
        :class:`~besdrake.sim.effects.EffectError`). Shorthands: ``box_friction`` replaces the box's friction coefficient, ``box_mass`` (kg) its
        mass, ``box_offset`` (dx m, dy m, yaw rad; the shelf's ``box_start`` frame) moves its start on the shelf,
        ``pad_friction`` the finger pads' friction coefficient. ``limits``: "flag" simulates a plan beyond the joint
        limits and flags it, "raise" refuses one beyond the position limits (:class:`~besdrake.plan.PlanError`). The
        outcome's ``q_arm`` is what the encoders read (true angles minus a ``joint_offset``). Never raises for
        simulation trouble."""
        if not isinstance(plan, MotionPlan):
            raise PlanError(f"rollout needs a MotionPlan, got {type(plan).__name__}")
        if limits not in ("raise", "flag"):
            raise ValueError(f"limits must be 'raise' or 'flag', got {limits!r}")
        effs = self._effects(effects, box_mass, box_offset, pad_friction)
        report = plan.check_limits(self.robot.limits)
        if limits == "raise" and np.any(report.position > 0):
            raise PlanError(f"motion plan exceeds {self.robot.name}'s position limits: " + ", ".join(report.violations()))
        grip = GripperCommand.of(plan, self.robot)
        setup = self._reset(plan, grip, effs, box_friction)
        out = PickPlaceOutcome()
        out.limits_kept = not (np.any(report.position > 0) or np.any(report.velocity > 0))
        self._simulate(setup.plan.duration + self.criteria.tail, out)
        self._measure(out, plan, grip)
        if out.q_arm.size:
            out.q_arm = out.q_arm - setup.measurement_offset
            out.q_commanded = plan.sample(out.t)
        score(out, self.place_target, self.criteria)
        return out

    def _effects(self, effects: dict | None, box_mass, box_offset, pad_friction) -> dict:
        """The scenario's effects with ``effects`` and the shorthands merged in, validated and completed; a ValueError
        for an effect the task does not list."""
        from besdrake.sim.effects import EffectError, merge_effects
        from besdrake.task import effects_not_for, get_task

        extra = {k: dict(v or {}) for k, v in (effects or {}).items()}
        if box_mass is not None:
            extra["box_mass"] = {"delta": float(box_mass) - self.box_mass}
        if pad_friction is not None:
            extra["pad_friction"] = {"scale": float(pad_friction) / self.pad_friction}
        done = merge_effects(self.scenario.effects, extra)
        other = effects_not_for("pick_and_place", done)
        if other:
            raise EffectError(f"effect(s) {other} do not act on pick-and-place rollouts (those that do: "
                              f"{list(get_task('pick_and_place').effects)} and a user's plugin effects)")
        if box_offset is not None:
            dx, dy, yaw = (float(v) for v in box_offset)
            world = self.h.box_start.rotation().matrix() @ np.array([dx, dy, 0.0])
            bo = done.setdefault("box_pose_offset", {"x": 0.0, "y": 0.0, "yaw": 0.0})
            bo.update(x=bo["x"] + world[0], y=bo["y"] + world[1], yaw=bo["yaw"] + yaw)  # may pass the effect's bounds
        return done

    def _measure(self, out: PickPlaceOutcome, plan: MotionPlan, grip: GripperCommand) -> None:
        """Box path, lift, slip in the gripper, final pose and measured limits from the state log."""
        from pydrake.common.eigen_geometry import Quaternion
        from pydrake.math import RotationMatrix

        ts = np.asarray(self.log.sample_times()).copy()
        xs = np.asarray(self.log.data()).T.copy()
        x_now = self.h.plant.GetPositionsAndVelocities(self.plant_context)
        ts, xs = np.append(ts, out.sim_time), np.vstack([xs, x_now]) if xs.size else x_now[None, :]
        keep = np.all(np.isfinite(xs), axis=1)
        ts, xs = ts[keep], xs[keep]
        out.t, out.q_arm = ts, xs[:, self.h.arm_q]
        lim = self.robot.position_limits
        if np.any(out.q_arm < lim[:, 0] - LIMIT_TOLERANCE) or np.any(out.q_arm > lim[:, 1] + LIMIT_TOLERANCE):
            out.limits_kept = False
        if ts.size == 0:
            return
        quat, centre = xs[:, self._box_q:self._box_q + 4], xs[:, self._box_q + 4:self._box_q + 7]
        up = np.array([RotationMatrix(Quaternion(q / np.linalg.norm(q))).matrix()[:, 2] for q in quat[-1:]])[0]
        out.box_path = centre - self._rest_height * np.array([0, 0, 1.0])  # bottom centre while upright
        bottom = centre[-1] - self._rest_height * up
        out.box_position, out.box_quaternion = bottom, quat[-1] / np.linalg.norm(quat[-1])
        out.tilt = float(np.arccos(np.clip(up[2], -1.0, 1.0)))
        out.upright = out.tilt <= self.criteria.upright_tolerance
        target = self.place_target
        out.place_error = float(np.linalg.norm(bottom[:2] - target[:2]))
        out.on_table = bool(abs(bottom[2] - target[2]) <= self.criteria.rest_tolerance)
        out.flags["dropped"] = bool(bottom[2] < target[2] - self.criteria.rest_tolerance)
        self._lift_and_hold(out, ts, xs, grip)

    def _lift_and_hold(self, out: PickPlaceOutcome, ts: np.ndarray, xs: np.ndarray, grip: GripperCommand) -> None:
        """Grasped: after closing, the fingers stopped short of their command. Lifted: the box's bottom rose ``lift_clearance`` above its start. Held: from that instant until the gripper
        command opens (or the end), the box's position in the tool frame moved less than ``slip_tolerance``."""
        t_closed = grip.closed_time()
        if t_closed is not None:
            i = min(int(np.searchsorted(ts, t_closed + GRASP_SETTLE)), len(ts) - 1)
            commanded = grip.joint_positions(self.robot, grip.sample([t_closed]))[0]
            out.grasped = bool(np.all(np.abs(xs[i, self.h.gripper_joint_q] - commanded) > GRASP_GAP))
        z = xs[:, self._box_q + 6] - self._rest_height
        above = np.nonzero(z >= self.box_start[2] + self.criteria.lift_clearance)[0]
        out.lifted = bool(above.size)
        if not out.lifted:
            return
        t_open = grip.release_time()
        t_stop = t_open if t_open is not None else ts[-1]
        idx = [i for i in range(int(above[0]), len(ts)) if ts[i] <= t_stop][::2]
        plant, tool = self.h.plant, self.h.tool_frame
        rel = []
        for i in idx:
            plant.SetPositions(self._scratch, xs[i, :plant.num_positions()])
            rel.append(tool.CalcPoseInWorld(self._scratch).inverse().multiply(xs[i, self._box_q + 4:self._box_q + 7]))
        rel = np.array(rel)
        out.max_slip = float(np.max(np.linalg.norm(rel - rel[0], axis=1))) if len(rel) else 0.0
        out.held = out.max_slip <= self.criteria.slip_tolerance
