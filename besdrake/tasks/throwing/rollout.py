"""The throwing task's rollout black box: :class:`ThrowRollout` executes a :class:`~besdrake.plan.MotionPlan`
and returns an :class:`~besdrake.tasks.throwing.outcome.Outcome` (the stages reach it through the task:
``besdrake.sim.rollout.Rollout(scenario)`` asks the scenario's task for its rollout).

Built once per process (about 0.3 s), then every call

1. resets the Context to the default one (``SetTimeStateAndParametersFrom``, ~0.1 ms; this also resets
   the SceneGraph's geometry state, so effects from an earlier rollout never leak),
2. applies the scenario's and the caller's effects (:mod:`besdrake.sim.effects`),
3. swaps the plan in with ``TrajectorySource.UpdateTrajectory`` and places the ball at rest in the scoop,
4. advances the simulator in chunks of ``release.check_interval`` and, between chunks, checks whether the
   ball has left the scoop for good: no contact now, and its predicted free flight keeps ``release.margin``
   from the scoop's surfaces while the scoop follows the commanded plan (no per-step Python; the plant computes
   its output ports only when read, and the check reads the contact results only once the ball is more than
   1 mm off every scoop surface: a read costs a contact solve, a geometric test about 15 us),
5. finds the release instant in the per-step state log (the last step in which the ball's velocity change
   differs from gravity's) and computes the flight from the state there (:mod:`besdrake.tasks.throwing.flight`).

Stopping the simulation at release is exact for the ball as long as nothing touches it again; the re-catch
prediction covers the scoop (links other than the scoop do not collide in the model). The joint
trajectories in the Outcome therefore end shortly after the release.

A solver error or a diverging state gives an Outcome with ``flags["sim_failed"]``; a malformed plan or a
plan beyond the position limits raises :class:`~besdrake.plan.PlanError` (``limits="raise"``, the default)
or is simulated and flagged (``limits="flag"``, for learning loops exploring freely).
"""

from __future__ import annotations

import numpy as np

from pydrake.math import RigidTransform

from besdrake.plan import MotionPlan, PlanError, PlanLimitError
from besdrake.sim.diagram import SimHandles, build_diagram
from besdrake.sim.effects import EffectError, apply_effects, merge_effects, set_gains
from besdrake.task import effects_not_for
from besdrake.tasks.throwing.effects import ThrowSetup
from besdrake.sim.scenario import Scenario, load_scenario
from besdrake.tasks.throwing.flight import fly
from besdrake.tasks.throwing.outcome import FLAG_NAMES, Outcome
from besdrake.tasks.throwing.scoop import Scoop

#: Measured joint angles may overshoot a position limit by this much (rad) before the flag is raised.
LIMIT_TOLERANCE = 0.01
#: Ball speeds above this (m/s) in the simulation mean divergence.
DIVERGENCE_SPEED = 50.0


class ThrowRollout:
    """One Diagram, reused for many throws: ``ThrowRollout("nominal").rollout(plan, effects)``."""

    #: The plant's output ports are computed when read (Drake's ``use_sampled_output_ports`` off): the same dynamics bit
    #: for bit, and a step does not compute reaction forces and contact results that nothing reads; the contact results
    #: are read only when the ball is off the scoop's surfaces (:meth:`_ball_outside`), where each read costs a solve.
    sampled_output_ports = False

    def __init__(self, scenario: Scenario | str = "nominal", meshcat=None) -> None:
        from pydrake.systems.analysis import Simulator

        self.scenario = load_scenario(scenario) if not isinstance(scenario, Scenario) else scenario
        self.handles: SimHandles = build_diagram(self.scenario, meshcat=meshcat, sampled_output_ports=self.sampled_output_ports)
        h = self.handles
        self.robot = self.scenario.robot
        self.scoop = Scoop.of(self.robot)
        self.simulator = Simulator(h.diagram)
        self.context = self.simulator.get_mutable_context()
        self.default_context = h.diagram.CreateDefaultContext()
        self.plant_context = h.plant.GetMyMutableContextFromRoot(self.context)
        self.scene_graph_context = h.scene_graph.GetMyMutableContextFromRoot(self.context)
        self.logger_log = h.state_logger.FindMutableLog(self.context)
        self._nq = h.plant.num_positions()
        # Indices of the arm and ball in the plant's state vector.
        plant = h.plant
        self._arm_q_idx = np.array([plant.GetJointByName(n, h.arm).position_start() for n in self.robot.joint_names])
        self._arm_v_idx = np.array([plant.GetJointByName(n, h.arm).velocity_start() for n in self.robot.joint_names])
        ball = h.scene.ball_body
        self._ball_q0 = ball.floating_positions_start()  # quaternion (4) then position (3)
        self._ball_v0 = self._nq + ball.floating_velocities_start_in_v()  # angular (3) then linear (3)
        self._gravity = plant.gravity_field().gravity_vector()
        self._scratch = h.plant.CreateDefaultContext()  # FK for the re-catch check, never simulated
        self._contact_port = plant.get_contact_results_output_port()  # looked up once: read after every chunk
        self._ball_index = ball.index()
        #: Time (s) after a tentative release over which the scoop's planned path is checked for a re-catch.
        self.recatch_horizon = 0.3
        #: Time (s) of a plan's initial hold that is still simulated (ball and contact settle).
        self.settle_time = 0.01
        self._skip = 0.0
        #: Time (s) by which the reference leads the plan (see rollout()); one time step.
        self.reference_lead = self.scenario.time_step

    # ------------------------------------------------------------------ helpers
    def _check_plan(self, plan: MotionPlan, limits: str):
        if not isinstance(plan, MotionPlan):
            raise PlanError(f"rollout needs a MotionPlan, got {type(plan).__name__}")
        report = plan.check_limits(self.robot.limits)  # validates the plan first
        if limits not in ("raise", "flag"):
            raise ValueError(f"limits must be 'raise' or 'flag', got {limits!r}")
        exceeded = bool(np.any(report.position > 0) or np.any(report.velocity > 0))
        if limits == "raise" and np.any(report.position > 0):
            raise PlanLimitError(f"motion plan exceeds {self.robot.name}'s position limits: " + ", ".join(v for v in report.violations() if "position" in v))
        return exceeded

    def _scoop_pose(self):
        h = self.handles
        return h.plant.CalcRelativeTransform(self.plant_context, h.plant.world_frame(), h.scene.scoop_frame)

    def _place_ball(self, q0: np.ndarray, v0: np.ndarray, radius: float, offset: np.ndarray | None = None) -> None:
        """Put the arm at the plan's start (sagged under gravity to where its PD servos hold it, when at rest)
        and the ball at rest in the scoop's funnel, ``offset`` (m, scoop plane) off-centre."""
        h = self.handles
        plant = h.plant
        plant.SetPositions(self.plant_context, h.arm, q0)
        plant.SetVelocities(self.plant_context, h.arm, v0)
        if not np.any(v0):
            # Static equilibrium of the servos: kp (q0 - q) + tau_gravity(q) = 0, two fixed-point steps.
            kp = np.array([a.get_controller_gains().p for a in h.actuators])
            if np.all(kp > 0):
                q = np.array(q0, dtype=float)
                for _ in range(2):
                    tau_g = plant.CalcGravityGeneralizedForces(self.plant_context)[self._arm_v_idx]
                    q = q0 + tau_g / kp
                    plant.SetPositions(self.plant_context, h.arm, q)
        X_WS = self._scoop_pose()
        dx, dy = (0.0, 0.0) if offset is None else (float(v) for v in offset)
        # 45-degree walls: a centre moved sideways by d towards a wall must rise by d to keep touching it.
        lift = (abs(dx) + abs(dy)) * np.tan(self.scoop.wall_angle)
        p_S = np.array([dx, dy, self.scoop.rest_height(radius) + (1e-4 + lift if lift else 0.0)])
        p = X_WS.multiply(p_S)
        plant.SetFreeBodyPose(self.plant_context, h.scene.ball_body, RigidTransform(X_WS.rotation(), p))
        plant.SetVelocities(self.plant_context, h.scene.ball_instance, np.zeros(6))

    def _initial_hold(self, plan: MotionPlan, qd: np.ndarray) -> float:
        """Seconds of the plan's initial hold (still at its first sample) that need not be simulated;
        ``qd``: the plan's knot velocities."""
        moving = np.any(np.abs(plan.q - plan.q[0]) > 1e-12, axis=1) | np.any(qd != 0.0, axis=1)
        if not np.any(moving):
            return 0.0
        i = int(np.argmax(moving))
        return max(0.0, float(plan.t[i - 1]) - self.settle_time) if i > 0 else 0.0

    def _ball_outside(self, radius: float) -> tuple[bool, bool, bool]:
        """(left the scoop for good, touching the floor, diverged) for the current state.

        The ball has left for good when it touches no scoop geometry now and its free flight over the next
        ``recatch_horizon`` s keeps at least ``release.margin`` from every scoop surface while the scoop
        follows the commanded plan (so a slow lob that falls back onto the scoop is simulated on). A ball within 1 mm
        of a scoop surface has not left: tested first, from the geometry (about 20 us), so that the contact results are
        read only near a release (with output ports computed when read, each read costs a contact solve).
        """
        x = self.handles.plant.GetPositionsAndVelocities(self.plant_context)
        p = x[self._ball_q0 + 4 : self._ball_q0 + 7]
        v = x[self._ball_v0 + 3 : self._ball_v0 + 6]
        speed = float(np.sqrt(v @ v))
        if not (speed <= DIVERGENCE_SPEED) or not np.isfinite(x).all():  # NaN fails the comparison too
            return False, False, True
        on_floor = bool(p[2] <= radius + 1e-3)
        if self._near_scoop(p, radius) or self._ball_touching():
            return False, on_floor, False
        return self._no_recatch(p, v, radius), on_floor, False

    def _near_scoop(self, p: np.ndarray, radius: float) -> bool:
        """True when the ball centred at ``p`` (world) is within 1 mm of touching a scoop surface (or inside it)."""
        h = self.handles
        x, y, z = h.plant.CalcPointsPositions(self.plant_context, h.plant.world_frame(), p.reshape(3, 1), h.scene.scoop_frame)[:, 0]
        return self.scoop.distance_to_point(float(x), float(y), float(z)) < radius + 1e-3

    def _ball_touching(self) -> bool:
        """True when the ball is in contact with anything now: the plant's contact results for the current state (an
        extra contact solve, about a step's cost: read only when the geometry cannot tell)."""
        contacts = self._contact_port.Eval(self.plant_context)
        ball = self._ball_index
        for i in range(contacts.num_point_pair_contacts()):
            info = contacts.point_pair_contact_info(i)
            if info.bodyA_index() == ball or info.bodyB_index() == ball:
                return True
        return False

    def _no_recatch(self, p: np.ndarray, v: np.ndarray, radius: float) -> bool:
        """True when the ball, flying freely from (p, v), keeps ``release.margin`` from every scoop surface while
        the scoop follows the commanded plan for ``recatch_horizon`` s (sampled every 10 ms)."""
        h = self.handles
        plant = h.plant
        t0 = self.context.get_time() + self._skip
        taus = np.arange(0.01, self.recatch_horizon + 1e-9, 0.01)
        qs = self._cmd.sample(t0 + taus)
        balls = p + np.outer(taus, v) + 0.5 * np.outer(taus * taus, self._gravity)
        self._scratch.SetTimeStateAndParametersFrom(self.plant_context)
        local = np.empty_like(balls)
        world, scoop = plant.world_frame(), h.scene.scoop_frame
        for i, q in enumerate(qs):
            plant.SetPositions(self._scratch, h.arm, q)
            local[i] = plant.CalcPointsPositions(self._scratch, world, balls[i].reshape(3, 1), scoop)[:, 0]
        return bool(np.all(self.scoop.distance(local) >= radius + self.scenario.release.margin))

    # ------------------------------------------------------------------ main
    def rollout(self, plan: MotionPlan, effects: dict | None = None, limits: str = "raise") -> Outcome:
        """Simulate ``plan`` with ``effects`` ``{name: {param: value}}``; never raises for simulation trouble."""
        plan_limit_exceeded = self._check_plan(plan, limits)
        effects_done = merge_effects(self.scenario.effects, effects)
        other = effects_not_for("throwing", effects_done)
        if other:
            raise EffectError(f"effect(s) {other} do not act on throwing rollouts")
        setup, cmd, skip = self._prepare(plan, effects_done)
        out = Outcome(effects=effects_done, scenario=self.scenario.name)
        flags = {k: False for k in FLAG_NAMES}
        rel = self.scenario.release
        separated, on_floor, diverged = self._simulate(cmd.duration + rel.tail - skip, setup.ball_radius, out, flags, skip)
        ts, q_arm, ball_p, ball_v = self._read_log(skip, out)
        out.joint_t = ts
        out.q_measured = q_arm - setup.measurement_offset
        out.q_commanded = plan.sample(ts)
        measured_over = np.any(self.robot.position_limits[:, 0] - LIMIT_TOLERANCE > q_arm) or np.any(q_arm > self.robot.position_limits[:, 1] + LIMIT_TOLERANCE)
        flags["joint_limit_exceeded"] = bool(plan_limit_exceeded or measured_over)
        if flags["sim_failed"] or not (separated or on_floor):
            if not flags["sim_failed"]:
                flags["never_released"] = True
                out.message = out.message or f"ball still in the scoop {rel.tail:g} s after the plan ended"
            out.ball_t, out.ball_path = ts, ball_p
            out.flags = flags
            return out
        self._release_and_flight(out, ts, ball_p, ball_v, setup)
        if np.linalg.norm(out.release_velocity) < rel.min_speed:
            flags["dropped_early"] = True
            out.message = f"ball fell out of the scoop at t={out.release_time:.3f} s with {np.linalg.norm(out.release_velocity):.2f} m/s"
        out.flags = flags
        return out

    def _prepare(self, plan: MotionPlan, effects_done: dict) -> tuple[ThrowSetup, MotionPlan, float]:
        """Reset the Context, apply the effects, swap the plan in and place the arm and the ball; returns the effects'
        setup, the commanded plan (with knot velocities) and the seconds of the initial hold not simulated."""
        h = self.handles
        self.context.SetTimeStateAndParametersFrom(self.default_context)
        if h.gains_scaled:
            set_gains(h)
        setup = ThrowSetup(
            plan=plan,
            handles=h,
            context=self.context,
            plant_context=self.plant_context,
            scene_graph_context=self.scene_graph_context,
            ball_radius=h.scene.nominal_ball_radius,
            ball_mass=float(h.scene.ball_body.get_mass(self.plant_context)),
        )
        apply_effects(setup, effects_done)
        cmd = setup.plan
        qd_all = cmd.knot_velocities()
        if cmd.qd is None:  # the same interpolation, with the spline fitted once instead of at every sample()
            cmd = MotionPlan(t=cmd.t, q=cmd.q, qd=qd_all, meta=cmd.meta)
        self._cmd = cmd
        # The discrete plant's implicit PD acts on the state at the end of each step, but the source is
        # sampled at its start: lead the reference by one step so that the logged joint angles at time t
        # track the plan at t for every step size (a pure time shift: it does not change where the ball lands).
        # After its end a plan holds its last position at rest (a 1 ms stop segment if it ends moving;
        # Drake's PiecewisePolynomial would otherwise keep commanding the final velocity).
        if np.any(qd_all[-1] != 0.0):
            t_ext = np.append(cmd.t, cmd.duration + 1e-3)
            cmd_src = MotionPlan(t=t_ext, q=np.vstack([cmd.q, cmd.q[-1]]), qd=np.vstack([qd_all, np.zeros(cmd.q.shape[1])]))
        else:
            cmd_src = cmd
        # A plan that starts by holding still: the arm and the ball start at their static equilibrium, so
        # only the last ``settle_time`` s of that hold are simulated (the simulation clock runs ``skip`` s
        # behind the plan's; all reported times are plan times).
        skip = self._initial_hold(cmd, qd_all)
        self._skip = skip
        h.plan_source.UpdateTrajectory(cmd_src.trajectory(time_shift=-self.reference_lead - skip))
        self._place_ball(cmd.q[0], qd_all[0], setup.ball_radius, setup.ball_offset)
        self.logger_log.Clear()
        return setup, cmd, skip

    def _simulate(self, t_end: float, radius: float, out: Outcome, flags: dict[str, bool], skip: float) -> tuple[bool, bool, bool]:
        """Advance to ``t_end`` (simulation clock) in chunks, stopping once the ball has left the scoop for good, touches
        the floor or diverges; a solver error or divergence sets ``sim_failed``. Returns (separated, on_floor, diverged)."""
        rel = self.scenario.release
        separated = on_floor = diverged = False
        try:
            self.simulator.Initialize()
            t = 0.0
            while t < t_end - 1e-12:
                t = min(t + rel.check_interval, t_end)
                self.simulator.AdvanceTo(t)
                separated, on_floor, diverged = self._ball_outside(radius)
                if separated or on_floor or diverged:
                    break
        except RuntimeError as err:
            flags["sim_failed"] = True
            out.message = f"simulation failed at t={self.context.get_time() + skip:.3f} s: {err}"
        if diverged:
            flags["sim_failed"] = True
            out.message = f"simulation diverged at t={self.context.get_time() + skip:.3f} s"
        out.sim_time = float(self.context.get_time()) + skip
        return separated, on_floor, diverged

    def _read_log(self, skip: float, out: Outcome) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Plan times, arm joint angles, ball positions and velocities from the state log (the final state included,
        the skipped hold prepended, non-finite rows dropped)."""
        plant = self.handles.plant
        log = self.logger_log
        ts = np.asarray(log.sample_times()).copy() + skip
        xs = np.asarray(log.data()).T.copy().reshape(-1, plant.num_multibody_states())
        if ts.size == 0 or ts[-1] < out.sim_time - 1e-9:  # make sure the final state is included
            ts = np.append(ts, out.sim_time)
            xs = np.vstack([xs, plant.GetPositionsAndVelocities(self.plant_context)])
        if skip > 0.0:  # the skipped part of the hold: the state at its end, held
            ts = np.concatenate([[0.0], ts])
            xs = np.vstack([xs[:1], xs])
        finite = np.all(np.isfinite(xs), axis=1)
        ts, xs = ts[finite], xs[finite]
        return ts, xs[:, self._arm_q_idx], xs[:, self._ball_q0 + 4 : self._ball_q0 + 7], xs[:, self._ball_v0 + 3 : self._ball_v0 + 6]

    def _release_and_flight(self, out: Outcome, ts: np.ndarray, ball_p: np.ndarray, ball_v: np.ndarray, setup: ThrowSetup) -> None:
        """Release: the last sample whose velocity change is not gravity alone, before any floor contact; then the
        free flight from there to the touchdown."""
        airborne = ball_p[:, 2] > setup.ball_radius + 2e-3
        n = int(np.argmin(airborne)) if not np.all(airborne) else len(ts)
        dv = np.diff(ball_v[:n], axis=0) - self._gravity * np.diff(ts[:n])[:, None]
        pushed = np.nonzero(np.linalg.norm(dv, axis=1) > 1e-6)[0]
        k = int(pushed[-1]) + 1 if pushed.size else 0
        k = min(k, max(n - 1, 0))
        out.release_time = float(ts[k])
        out.release_position = ball_p[k].copy()
        out.release_velocity = ball_v[k].copy()
        flight = fly(
            ball_p[k],
            ball_v[k],
            setup.ball_radius,
            mass=setup.ball_mass,
            drag_coefficient=setup.drag_coefficient,
            air_density=setup.air_density,
            wind=setup.wind,
            gravity=float(-self._gravity[2]),
        )
        out.touchdown = flight.touchdown_position[:2].copy()
        out.touchdown_time = float(ts[k] + flight.duration)
        out.ball_t = np.concatenate([ts[: k + 1], ts[k] + flight.t[1:]])
        out.ball_path = np.vstack([ball_p[: k + 1], flight.path[1:]])
