"""The throwing task as a plug-in: a ball thrown from the robot's scoop onto a target on the floor.

Scene: the ball (in the scoop) and the floor (``models: ball, ground`` of the scenario). A rollout runs until
the ball has left the scoop for good and computes its flight (:class:`~besdrake.tasks.throwing.rollout.ThrowRollout`);
the outcome is the touchdown and the release state (:class:`~besdrake.tasks.throwing.outcome.Outcome`). The behaviour
features for Transferability: :mod:`besdrake.tasks.throwing.descriptor`.
"""

from __future__ import annotations

from pathlib import Path

from besdrake.task import Task, register_task


@register_task
class ThrowingTask(Task):
    name = "throwing"
    description = "throw a ball from a scoop onto a target on the floor (BesMan's COMPI experiments)"
    default_scenario = "nominal"
    object_markers = ("Ball",)
    effects = ("base_offset", "joint_offset", "actuator_lag", "gain_scale", "air_drag", "ball_placement", "ball",
               "scoop_friction", "scoop_mount")
    default_lab = "default_lab"
    learn_config = Path(__file__).resolve().parent / "learn.yaml"

    def scene(self):
        """The ball in the scoop and the floor (:class:`~besdrake.tasks.throwing.scene.ThrowScene`)."""
        from besdrake.tasks.throwing.scene import ThrowScene

        return ThrowScene()

    def learn_stages(self):
        """Label, segment, imitate, refine, transfer, diagnose, transfer_refined, template, pool, report
        (:mod:`besdrake.tasks.throwing.learn`)."""
        from besdrake.tasks.throwing.learn import STAGES

        return list(STAGES)

    def check_learn_config(self, config) -> None:
        """The refinement's stop and robustness settings, the template's reach refinement, the Transferability settings and the diagnosis experiment's
        design, checked before any stage runs."""
        from besdrake.tasks.throwing.learn import diagnosis_design, refinement_settings, template_reach_settings, transfer_config

        refinement_settings(config)
        template_reach_settings(config)
        transfer_config(config)
        if config["diagnosis"].get("enabled", True):
            diagnosis_design(config)

    def make_rollout(self, scenario, meshcat=None):
        from besdrake.tasks.throwing.rollout import ThrowRollout

        return ThrowRollout(scenario, meshcat=meshcat)

    def default_plan(self, rollout, amplitude: float | None = None, yaw: float = 0.0):
        """The default overhand throw (amplitude 0.35 unless given; ``yaw``: joint 1's angle, rad)."""
        from besdrake.tasks.throwing.throws import default_throw

        return default_throw(amplitude=0.35 if amplitude is None else amplitude, yaw=yaw)

    def record_replay(self, rollout, plan, outcome, meshcat, fps):
        """The arm as measured (then as commanded), the ball along its path and a marker at the touchdown."""
        from besdrake.tasks.throwing.replay import record_throw

        record_throw(rollout, plan, outcome, meshcat, fps)

    def reward(self, **settings):
        """:class:`~besdrake.tasks.throwing.reward.ThrowReward`: minus the touchdown's distance to the target, minus the
        limit penalties."""
        from besdrake.tasks.throwing.reward import ThrowReward

        return ThrowReward(**settings)

    def reward_from_dict(self, settings):
        from besdrake.tasks.throwing.reward import ThrowReward

        return ThrowReward.from_dict(settings)

    def behaviour_descriptor(self, plan, outcome):
        """The 17 features of a throw (release time and state, peak joint accelerations, half-time posture)."""
        from besdrake.tasks.throwing.descriptor import behaviour_descriptor

        return behaviour_descriptor(plan, outcome)

    def measurement_type(self) -> type:
        """:class:`~besdrake.tasks.throwing.measurement.ThrowMeasurement`: touchdown, ball marker, encoders."""
        from besdrake.tasks.throwing.measurement import ThrowMeasurement

        return ThrowMeasurement

    def scatter_effects(self, scenario, sd: float):
        """The ball's placement in the scoop, N(0, sd^2) per axis around the scenario's habit: the 9 placements of a
        3 x 3 Gauss-Hermite rule (:func:`~besdrake.tasks.throwing.effects.placement_quadrature`)."""
        from besdrake.tasks.throwing.effects import ball_placed, placement_quadrature

        placements, weights = placement_quadrature(sd)
        habit = dict(scenario.effects.get("ball_placement", {})) if scenario is not None else {}
        return [None] + [{"ball_placement": ball_placed(habit, d)} for d in placements[1:]], weights

    def make_lab(self, config, seed: int | None = None):
        """The throwing lab (:class:`~besdrake.tasks.throwing.lab.VirtualLab`) from a lab YAML path, name or mapping."""
        from besdrake.tasks.throwing.lab import VirtualLab, load_lab_config, parse_lab_config

        cfg = parse_lab_config(config) if isinstance(config, dict) else load_lab_config(config)
        return VirtualLab(cfg if seed is None else cfg.with_seed(seed))

    def diagnosis_model(self):
        """:class:`~besdrake.tasks.throwing.diagnosis.model.ThrowDiagnosis`: touchdown, ball flight and rest, joint
        tracking; diagnosis throws with repeats, sideways throws and tilt probes; the ball's placement scatter."""
        from besdrake.tasks.throwing.diagnosis.model import MODEL

        return MODEL

    def check_robot(self, robot) -> None:
        """Throwing needs a scoop: a fixed end effector with the scoop's geometry in its params."""
        from besdrake.tasks.throwing.scoop import Scoop

        Scoop.of(robot)

    def failed_outcome(self, message: str):
        from besdrake.tasks.throwing.outcome import FLAG_NAMES, Outcome

        flags = {k: False for k in FLAG_NAMES}
        flags["sim_failed"] = True
        return Outcome(flags=flags, message=message)
