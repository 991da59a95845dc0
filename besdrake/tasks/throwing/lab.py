"""The virtual lab: the Drake simulation plus hidden physical effects plus the measurement process of a
real lab, behind the same :class:`~besdrake.transfer.lab.Lab` interface as the real robot.

Configured by a YAML file (see ``diagrams/labs/default_lab.yaml``)::

    name: default_lab
    description: public text (written into logs; do not describe the hidden effects here)
    scenario: nominal                 # scenario name or path (relative to this file)
    seed: 0
    effects: {base_offset: {z: -0.03}}   # the hidden truth; never written into a log
    noise:
      touchdown_sd: 0.05              # m, per axis: throw-to-throw scatter not explained by ball placement
      ball_placement_sd: 0.002        # m, per axis: the ball's placement in the scoop, throw to throw
      mocap_rate_hz: 200              # ball marker sampling rate
      mocap_noise_sd: 0.001           # m, per axis, on every marker sample and on the touchdown
      mocap_dropout: 0.02             # probability that a frame misses the marker (NaN row)
      capture_volume: {min: [-0.5, -1.5, 0.0], max: [3.5, 1.5, 3.0]}   # m, world frame
      encoder_noise_sd: 0.0005        # rad, per joint sample
      joint_rate_hz: 500              # joint log rate
    record_ball_path: true
    record_joints: true
    plugins: [my_effects.py]          # user modules that register effects (relative to this file)

How one trial is measured (all random numbers from ``numpy.random.default_rng([seed, trial])``, so trial
``k`` measures the same whenever it is re-run, which makes resuming a run safe):

1. **Ball placement.** The ball is put into the scoop off-centre by (dx, dy) ~ N(0, ball_placement_sd^2)
   in the scoop's base plane, raised so that it rests against the funnel walls (the walls are at 45
   degrees, so by |dx| + |dy|), and simulated from there: it rolls back while the arm starts to swing
   and leaves a little differently. With the default throw, 2 mm SD gives 1-2 cm SD on the floor.
2. **Simulation** with the scenario's and the hidden effects (:meth:`besdrake.sim.Rollout.rollout`).
3. **Unexplained scatter.** The paper measured SD 4.5-7 cm for the touchdown of good throws (20 repetitions
   each). What the model does not explain (ball spin, seam, small release differences) is added as a
   horizontal release-velocity perturbation: the flight part of the path is shifted by
   ``delta * (t - t_release) / (t_touchdown - t_release)`` with delta ~ N(0, touchdown_sd^2) per axis, so the
   marker path and the touchdown stay consistent (exact for a drag-free flight).
4. **Motion capture.** The ball marker is sampled at ``mocap_rate_hz`` from the plan start until the
   touchdown, kept only while inside ``capture_volume``, with N(0, mocap_noise_sd^2) noise and dropouts.
   The touchdown is measured (with the same noise) if it lies inside the volume, otherwise flag
   ``ball_not_seen``.
5. **Encoders.** Commanded and measured joint angles at ``joint_rate_hz`` with N(0, encoder_noise_sd^2)
   noise; the log ends when the ball is in free flight (the simulation stops there).

A measured joint angle beyond a position limit switches the robot off, as in the paper: flags
``joint_limit_exceeded`` and ``aborted``, no touchdown. A plan beyond a position, velocity or acceleration
limit (a lab without a :class:`~besdrake.transfer.lab.SafetyGate` in front) is aborted the same way
without being simulated. The "SD of the touchdown position" throughout is
the pooled per-axis SD, sqrt((var x + var y) / 2).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from besdrake.plan import MotionPlan, PlanError
from besdrake.tasks.throwing.effects import ball_placed
from besdrake.transfer.lab import TrialCounter
from besdrake.transfer.lab_config import LabConfigError, _bool, _number, _seed, resolve_lab_path, scenario_path
from besdrake.tasks.throwing.measurement import ThrowMeasurement
from besdrake.plugins import load_plugins

#: Largest |dx| + |dy| (m) of the ball placement: keeps the ball well below the scoop's lip.
MAX_PLACEMENT_OFFSET = 0.008


# ---------------------------------------------------------------------------------------- config


@dataclass
class CaptureVolume:
    """Axis-aligned box (world frame, m) in which motion capture sees the ball marker."""

    min: np.ndarray = field(default_factory=lambda: np.array([-0.5, -1.5, 0.0]))
    max: np.ndarray = field(default_factory=lambda: np.array([3.5, 1.5, 3.0]))

    def __post_init__(self) -> None:
        self.min = np.asarray(self.min, dtype=float)
        self.max = np.asarray(self.max, dtype=float)
        if self.min.shape != (3,) or self.max.shape != (3,) or not (np.all(np.isfinite(self.min)) and np.all(np.isfinite(self.max))):
            raise LabConfigError("noise.capture_volume: min and max must be 3 finite numbers each (x, y, z in m)")
        if np.any(self.min >= self.max):
            raise LabConfigError(f"noise.capture_volume: min {self.min.tolist()} must be below max {self.max.tolist()} on every axis")

    def contains(self, p: np.ndarray) -> np.ndarray:
        """Boolean mask over points ``p`` (..., 3)."""
        p = np.asarray(p, dtype=float)
        return np.all((p >= self.min) & (p <= self.max), axis=-1)

    def to_dict(self) -> dict[str, list[float]]:
        return {"min": self.min.tolist(), "max": self.max.tolist()}


@dataclass
class NoiseConfig:
    """The lab's measurement process and throw-to-throw variation (SI units; see the module docstring)."""

    touchdown_sd: float = 0.05
    ball_placement_sd: float = 0.002
    mocap_rate_hz: float = 200.0
    mocap_noise_sd: float = 0.001
    mocap_dropout: float = 0.0
    capture_volume: CaptureVolume = field(default_factory=CaptureVolume)
    encoder_noise_sd: float = 0.0005
    joint_rate_hz: float = 500.0

    #: (low, high) allowed for each number.
    RANGES = {
        "touchdown_sd": (0.0, 1.0),
        "ball_placement_sd": (0.0, 0.005),
        "mocap_rate_hz": (1.0, 2000.0),
        "mocap_noise_sd": (0.0, 0.1),
        "mocap_dropout": (0.0, 0.9),
        "encoder_noise_sd": (0.0, 0.1),
        "joint_rate_hz": (1.0, 5000.0),
    }

    def sensors(self) -> dict[str, Any]:
        """The public sensor facts (what a lab's data sheet says), written into logs."""
        return {
            "mocap_rate_hz": self.mocap_rate_hz,
            "mocap_noise_sd_m": self.mocap_noise_sd,
            "capture_volume_m": self.capture_volume.to_dict(),
            "joint_rate_hz": self.joint_rate_hz,
            "encoder_noise_sd_rad": self.encoder_noise_sd,
        }


@dataclass
class LabConfig:
    """A validated virtual-lab configuration (see the module docstring for the YAML layout)."""

    name: str
    scenario: str = "nominal"
    effects: dict[str, dict[str, float]] = field(default_factory=dict)
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    seed: int = 0
    record_ball_path: bool = True
    record_joints: bool = True
    plugins: list[str] = field(default_factory=list)
    description: str = ""
    path: Path | None = None
    #: Joint positions (rad) the robot stands at before its first trial; None: it is moved to each plan's start.
    home_pose: tuple[float, ...] | None = None

    def with_seed(self, seed: int) -> "LabConfig":
        """A copy with another noise seed."""
        new = copy.deepcopy(self)
        new.seed = _seed(seed, "seed")
        return new


def parse_lab_config(data: Any, base_dir: Path | None = None, name: str = "lab") -> LabConfig:
    """Validate a lab config mapping (as read from YAML); paths are resolved against ``base_dir``."""
    from besdrake.sim.effects import EffectError, normalize_effects

    if not isinstance(data, dict):
        raise LabConfigError(f"a lab config must be a mapping, got {type(data).__name__}")
    known = {"name", "description", "scenario", "effects", "noise", "seed", "record_ball_path", "record_joints", "plugins", "home_pose"}
    unknown = set(data) - known
    if unknown:
        raise LabConfigError(f"lab config has unknown field(s) {sorted(unknown)}; known: {sorted(known)}")
    noise, record = _noise_and_recording(data)
    plugins = _plugins(data, base_dir)
    load_plugins(plugins)  # effects named in the config may come from them
    scenario = _checked_scenario(data, base_dir)
    home = _home_pose(data.get("home_pose"))
    try:
        effects = normalize_effects(data.get("effects") or {})
    except EffectError as err:
        raise LabConfigError(f"lab config effects: {err}") from err
    lab_name = data.get("name", name)
    if not isinstance(lab_name, str) or not lab_name:
        raise LabConfigError(f"lab config field name must be a non-empty string, got {lab_name!r}")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise LabConfigError("lab config field description must be text")
    return LabConfig(
        name=lab_name,
        scenario=scenario,
        effects=effects,
        noise=noise,
        seed=_seed(data.get("seed", 0), "seed"),
        record_ball_path=record["record_ball_path"],
        record_joints=record["record_joints"],
        plugins=plugins,
        description=description.strip(),
        home_pose=home,
    )


def _noise_and_recording(data: dict) -> tuple[NoiseConfig, dict[str, bool]]:
    """The ``noise`` section, and the two recording switches (at the top level or inside ``noise``)."""
    noise_d = data.get("noise") or {}
    if not isinstance(noise_d, dict):
        raise LabConfigError(f"lab config field noise must be a mapping, got {noise_d!r}")
    noise_d = dict(noise_d)
    record = {}
    for key in ("record_ball_path", "record_joints"):  # accepted at the top level or inside noise
        if key in data and key in noise_d:
            raise LabConfigError(f"lab config gives {key} both at the top level and under noise")
        record[key] = _bool(key, data[key] if key in data else noise_d.pop(key, True))
    noise_known = set(NoiseConfig.RANGES) | {"capture_volume"}
    unknown = set(noise_d) - noise_known
    if unknown:
        raise LabConfigError(f"lab config noise has unknown field(s) {sorted(unknown)}; known: {sorted(noise_known)}")
    kwargs: dict[str, Any] = {k: _number(f"noise.{k}", noise_d[k], *NoiseConfig.RANGES[k]) for k in NoiseConfig.RANGES if k in noise_d}
    if "capture_volume" in noise_d:
        kwargs["capture_volume"] = _capture_volume(noise_d["capture_volume"])
    return NoiseConfig(**kwargs), record


def _capture_volume(cv: Any) -> CaptureVolume:
    if not isinstance(cv, dict) or set(cv) != {"min", "max"}:
        raise LabConfigError(f"noise.capture_volume must be {{min: [x, y, z], max: [x, y, z]}} in m, got {cv!r}")
    try:
        return CaptureVolume(np.asarray(cv["min"], float), np.asarray(cv["max"], float))
    except (TypeError, ValueError) as err:
        if isinstance(err, LabConfigError):
            raise
        raise LabConfigError(f"noise.capture_volume: {err}") from err


def _plugins(data: dict, base_dir: Path | None) -> list[str]:
    """The plugin files, relative paths resolved against ``base_dir``."""
    plugins = data.get("plugins") or []
    if not isinstance(plugins, list) or not all(isinstance(p, str) for p in plugins):
        raise LabConfigError(f"lab config field plugins must be a list of file paths, got {plugins!r}")
    return [str(Path(p) if Path(p).is_absolute() or base_dir is None else (base_dir / p)) for p in plugins]


def _checked_scenario(data: dict, base_dir: Path | None) -> str:
    """The scenario field resolved (:func:`~besdrake.transfer.lab_config.scenario_path`) and loaded once, so a
    missing or broken scenario is named now, not at the first trial."""
    from besdrake.sim.scenario import ScenarioError, load_scenario

    scenario = scenario_path(data.get("scenario", "nominal"), base_dir)
    try:
        load_scenario(scenario)
    except ScenarioError as err:
        raise LabConfigError(f"lab config scenario: {err}") from err
    return scenario


def _home_pose(home: Any) -> tuple[float, ...] | None:
    if home is None:
        return None
    if not isinstance(home, list) or len(home) != 6:
        raise LabConfigError(f"lab config field home_pose must be a list of 6 joint positions (rad), got {home!r}")
    return tuple(_number("home_pose", v, -np.pi * 2, np.pi * 2) for v in home)


def load_lab_config(path: str | Path) -> LabConfig:
    """Read and validate a lab YAML file (see :func:`resolve_lab_path`); :class:`LabConfigError` naming the file and
    the problem."""
    p = resolve_lab_path(path)
    if not p.is_file():
        raise LabConfigError(f"lab config file not found: {p}")
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as err:
        raise LabConfigError(f"lab config {p} is not valid YAML: {err}") from err
    try:
        cfg = parse_lab_config(data, base_dir=p.resolve().parent, name=p.stem)
    except LabConfigError as err:
        raise LabConfigError(f"{p}: {err}") from err
    except ValueError as err:  # e.g. a plugin that failed
        raise LabConfigError(f"{p}: {err}") from err
    cfg.path = p
    return cfg


# ---------------------------------------------------------------------------------------- simulation


class VirtualLab(TrialCounter):
    """A simulated lab with hidden effects and a real lab's measurement process (module docstring).

    ``VirtualLab(config)`` with a :class:`LabConfig`, a config mapping or the path of a lab YAML file. The Drake diagram is
    built on the first :meth:`execute` (about 1 s) and reused."""

    #: The Measurement class of its trials (the safety gate's refusals and the log use it).
    measurement_type = ThrowMeasurement

    def __init__(self, config: LabConfig | dict | str | Path) -> None:
        if isinstance(config, dict):
            config = parse_lab_config(config)
        self.config = config if isinstance(config, LabConfig) else load_lab_config(config)
        self.name = self.config.name
        self._rollout = None
        self._robot = None
        self._pose = None if self.config.home_pose is None else np.array(self.config.home_pose, dtype=float)

    @property
    def robot(self):
        """The lab's robot (its scenario's robot file)."""
        if self._robot is None:
            from besdrake.sim.scenario import load_scenario

            self._robot = self._rollout.robot if self._rollout is not None else load_scenario(self.config.scenario).robot
        return self._robot

    def current_pose(self) -> np.ndarray | None:
        """Where the robot stands: the config's ``home_pose``, then the last executed plan's end pose; None
        when the lab has no home pose (the virtual robot is put at each plan's start)."""
        return None if self._pose is None else self._pose.copy()

    def description(self) -> dict[str, Any]:
        """Public facts for a log: name, description, scenario, sensors, what is recorded (no hidden truth)."""
        c = self.config
        return {
            "name": c.name,
            "kind": "virtual",
            "description": c.description,
            "scenario": Path(c.scenario).stem if str(c.scenario).endswith((".yaml", ".yml")) else c.scenario,
            "robot": self.robot.name,
            "sensors": c.noise.sensors(),
            "record_ball_path": c.record_ball_path,
            "record_joints": c.record_joints,
        }

    @property
    def rollout(self):
        """The (lazily built) simulation."""
        if self._rollout is None:
            from besdrake.sim.rollout import Rollout

            self._rollout = Rollout(self.config.scenario)
        return self._rollout

    def execute(self, plan: MotionPlan, trial: int | None = None) -> ThrowMeasurement:
        """Run ``plan`` as trial ``trial`` (default: the next one) and measure it."""
        if not isinstance(plan, MotionPlan):
            raise TypeError(f"VirtualLab.execute needs a MotionPlan, got {type(plan).__name__}")
        trial = self.next_trial(trial)
        c = self.config
        rng = np.random.default_rng([c.seed, trial])
        offset, delta, td_noise = self._trial_draws(rng)
        meta = self._meta(plan)
        refused = self._refusal(plan, trial, meta)
        if refused is not None:
            return refused
        # This trial's placement adds to any systematic placement offset among the hidden effects.
        effects = {name: dict(values) for name, values in c.effects.items()}
        # The sum stays where a ball can sit in the scoop: within the effect's bounds.
        effects["ball_placement"] = ball_placed(effects.get("ball_placement"), offset)
        try:
            out = self.rollout.rollout(plan, effects=effects, limits="flag")
        except PlanError as err:
            return ThrowMeasurement(trial=trial, plan=plan, flags={"aborted": True}, message=f"aborted: malformed plan: {err}", meta=meta)
        if self._pose is not None:
            self._pose = np.array(plan.q[-1], dtype=float)  # the robot stays where the plan left it
        flags, message = self._flags(out)
        ball_t, path, true_td, t_end = self._scattered_path(out, delta)
        touchdown = None
        if true_td is not None and not flags["aborted"]:
            touchdown, message = self._seen_touchdown(true_td, path, td_noise, flags, message)
        m_ball_t = m_ball_path = None
        if c.record_ball_path:
            m_ball_t, m_ball_path = self._mocap(ball_t, path, t_end, rng)
        joint_t = q_cmd = q_meas = None
        if c.record_joints and out.joint_t.size:
            joint_t, q_cmd, q_meas = self._encoders(plan, out.joint_t, out.q_measured, rng)
        return ThrowMeasurement(trial=trial, plan=plan, touchdown=touchdown, ball_t=m_ball_t, ball_path=m_ball_path,
                                joint_t=joint_t, q_commanded=q_cmd, q_measured=q_meas,
                                flags={k: v for k, v in flags.items() if v}, message=message, meta=meta)

    def _trial_draws(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """This trial's ball placement offset (capped), unexplained touchdown scatter and touchdown measurement noise
        (drawn first, in this order, so that a trial is reproducible from the seed)."""
        n = self.config.noise
        offset = rng.normal(0.0, n.ball_placement_sd, 2)
        if np.abs(offset).sum() > MAX_PLACEMENT_OFFSET:
            offset *= MAX_PLACEMENT_OFFSET / np.abs(offset).sum()
        return offset, rng.normal(0.0, n.touchdown_sd, 2), rng.normal(0.0, n.mocap_noise_sd, 2)

    def _meta(self, plan: MotionPlan) -> dict[str, Any]:
        n = self.config.noise
        return {
            "lab": self.config.name,
            "plan_name": str(plan.meta.get("name", plan.meta.get("generator", ""))),
            "executed_at": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "mocap_rate_hz": n.mocap_rate_hz,
            "joint_rate_hz": n.joint_rate_hz,
        }

    def _refusal(self, plan: MotionPlan, trial: int, meta: dict[str, Any]) -> ThrowMeasurement | None:
        """The aborted trial of a malformed plan or one beyond the joint limits (no safety gate in front: the robot's
        drives stop it, as in the paper), else None."""
        try:
            over = plan.check_limits(self.robot.limits).violations()
        except PlanError as err:
            return ThrowMeasurement(trial=trial, plan=plan, flags={"aborted": True}, message=f"aborted: malformed plan: {err}", meta=meta)
        if not over:
            return None
        return ThrowMeasurement(
            trial=trial, plan=plan, flags={"joint_limit_exceeded": True, "aborted": True},
            message="aborted: the plan drove a joint beyond its limits and the robot switched itself off: " + "; ".join(over),
            meta=meta)

    @staticmethod
    def _flags(out) -> tuple[dict[str, bool], str]:
        """The trial's flags and message from the rollout's outcome (a failed simulation or a joint beyond its limit
        aborts the trial)."""
        flags = {
            "dropped_early": bool(out.flags.get("dropped_early")),
            "never_released": bool(out.flags.get("never_released")),
            "joint_limit_exceeded": bool(out.flags.get("joint_limit_exceeded")),
            "aborted": False,
            "ball_not_seen": False,
        }
        message = out.message
        if out.flags.get("sim_failed"):
            flags["aborted"] = True
            message = f"aborted: {out.message}"
        if flags["joint_limit_exceeded"]:
            flags["aborted"] = True
            message = "aborted: a joint went beyond its position limit and the robot switched itself off"
        return flags, message

    @staticmethod
    def _scattered_path(out, delta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, float]:
        """The true ball path with the unexplained scatter (a horizontal release-velocity perturbation ``delta`` reached
        at the touchdown): ``(t, path, true touchdown or None, end time)``."""
        ball_t = np.asarray(out.ball_t, float)
        path = np.asarray(out.ball_path, float).copy()
        true_td = None
        if out.touchdown is not None and out.release_time is not None and out.touchdown_time is not None:
            span = max(out.touchdown_time - out.release_time, 1e-9)
            frac = np.clip((ball_t - out.release_time) / span, 0.0, 1.0)
            path[:, :2] += frac[:, None] * delta
            true_td = np.asarray(out.touchdown, float) + delta
        t_end = out.touchdown_time if out.touchdown_time is not None else (float(ball_t[-1]) if ball_t.size else 0.0)
        return ball_t, path, true_td, t_end

    def _seen_touchdown(self, true_td: np.ndarray, path: np.ndarray, td_noise: np.ndarray, flags: dict[str, bool],
                        message: str) -> tuple[np.ndarray | None, str]:
        """The measured touchdown (with noise) if the capture volume sees it, else None with ``ball_not_seen`` set."""
        volume = self.config.noise.capture_volume
        radius = float(path[-1, 2]) if path.size else 0.0
        if volume.contains(np.array([true_td[0], true_td[1], radius])):
            return true_td + td_noise, message
        flags["ball_not_seen"] = True
        return None, message or f"touchdown outside the capture volume {volume.to_dict()}"

    def _mocap(self, t: np.ndarray, path: np.ndarray, t_end: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        n = self.config.noise
        if t.size < 2:
            return np.zeros(0), np.zeros((0, 3))
        frames = np.arange(0, int(np.floor(t_end * n.mocap_rate_hz + 1e-9)) + 1)
        ft = frames / n.mocap_rate_hz
        p = np.column_stack([np.interp(ft, t, path[:, i]) for i in range(3)])
        noise = rng.normal(0.0, n.mocap_noise_sd, p.shape)
        lost = rng.random(len(ft)) < n.mocap_dropout
        inside = n.capture_volume.contains(p)
        p = p + noise
        p[lost] = np.nan
        return ft[inside], p[inside]

    def _encoders(self, plan: MotionPlan, t: np.ndarray, q_meas: np.ndarray, rng: np.random.Generator):
        n = self.config.noise
        jt = np.arange(0, int(np.floor(t[-1] * n.joint_rate_hz + 1e-9)) + 1) / n.joint_rate_hz
        q_cmd = plan.sample(jt)
        q = np.column_stack([np.interp(jt, t, q_meas[:, i]) for i in range(q_meas.shape[1])])
        q = q + rng.normal(0.0, n.encoder_noise_sd, q.shape)
        return jt, q_cmd, q


__all__ = ["CaptureVolume", "LabConfig", "LabConfigError", "NoiseConfig", "VirtualLab", "load_lab_config", "parse_lab_config"]
