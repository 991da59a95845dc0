"""The pick-and-place task as a plug-in (for ``besdrake.task``; needs the task interface of the main branch).

Scene: the scenario's ``fixtures`` (shelf, table, floor; frames ``box_start``, ``place_target``) and ``box``; the
robot needs a gripper. A rollout simulates the arm plan and the gripper command in ``plan.meta["gripper"]``
(:class:`~besdrake.tasks.pick_and_place.rollout.PickPlaceRollout`); the outcome is a
:class:`~besdrake.tasks.pick_and_place.outcome.PickPlaceOutcome` (lift, hold, place error, upright, collisions).
"""

from __future__ import annotations

from pathlib import Path

from besdrake.task import Task, register_task


@register_task
class PickAndPlaceTask(Task):
    name = "pick_and_place"
    description = "pick a box from a shelf and put it upright on a table with a gripper, held by friction only"
    default_scenario = "pick_and_place"
    object_markers = ("Box back",)
    #: The box's pose offset, mass and the pads' friction (:mod:`besdrake.tasks.pick_and_place.effects`) and the plan
    #: effects (encoder offsets, actuator lag); the rollout refuses any other.
    effects = ("joint_offset", "actuator_lag", "box_pose_offset", "box_mass", "pad_friction")
    default_lab = "pick_and_place_lab"

    learn_config = Path(__file__).resolve().parent / "learn.yaml"

    def learn_stages(self):
        """Demonstrations, refinement in simulation, lab trials, report (:mod:`besdrake.tasks.pick_and_place.learn`)."""
        from besdrake.tasks.pick_and_place.learn import STAGES

        return list(STAGES)

    def make_rollout(self, scenario, meshcat=None):
        from besdrake.tasks.pick_and_place.rollout import PickPlaceRollout

        return PickPlaceRollout(scenario, meshcat=meshcat)

    def check_robot(self, robot) -> None:
        """Pick-and-place needs a gripper."""
        from besdrake.robot import RobotError

        if robot.end_effector.gripper is None:
            raise RobotError(f"{robot.path or robot.name}: end_effector: pick-and-place needs a gripper, "
                             f"robot {robot.name!r} has a {robot.end_effector.type!r} end effector")

    def default_plan(self, rollout, **shape):
        """The scripted pick-and-place of the scene's box (inverse kinematics at the grasp and place poses)."""
        self._no_shape(self.name, shape)
        from besdrake.tasks.pick_and_place.scripted import scripted_plan_for

        return scripted_plan_for(rollout)

    def make_lab(self, config, seed: int | None = None):
        """The virtual pick-and-place lab (:class:`~besdrake.tasks.pick_and_place.lab.PickPlaceLab`) from a lab YAML
        path, name or mapping."""
        from besdrake.tasks.pick_and_place.lab import PickPlaceLab
        from besdrake.tasks.pick_and_place.lab_config import load_pick_place_lab_config, parse_pick_place_lab_config

        cfg = parse_pick_place_lab_config(config) if isinstance(config, dict) else load_pick_place_lab_config(config)
        return PickPlaceLab(cfg if seed is None else cfg.with_seed(seed))

    def measurement_type(self) -> type:
        """:class:`~besdrake.tasks.pick_and_place.measurement.PickPlaceMeasurement`."""
        from besdrake.tasks.pick_and_place.measurement import PickPlaceMeasurement

        return PickPlaceMeasurement

    def record_replay(self, rollout, plan, outcome, meshcat, fps):
        """The arm, gripper and box as simulated, and a marker on the table place."""
        from besdrake.tasks.pick_and_place.replay import record_grasp

        record_grasp(rollout, plan, outcome, meshcat, fps)

    def diagnosis_model(self):
        """The pick-and-place trials as the diagnosis reads them
        (:class:`~besdrake.tasks.pick_and_place.diagnosis.model.PickPlaceDiagnosis`)."""
        from besdrake.tasks.pick_and_place.diagnosis.model import MODEL

        return MODEL

    def failed_outcome(self, message: str):
        from besdrake.tasks.pick_and_place.outcome import failed_outcome

        return failed_outcome(message)
