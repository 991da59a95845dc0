"""The pick-and-place task's effects: where the box truly stands (against where perception says), its mass and the
finger pads' friction. Registered after the registry's robot effects (:mod:`besdrake.sim.effects`) and the throwing
task's, in this order, when the registry is first read; they act on a :class:`PickPlaceSetup` and only the
pick-and-place rollout reads them (the task lists them in :attr:`~besdrake.task.Task.effects`, so they are no
candidates of another task's diagnosis).

The virtual pick-and-place lab hides its truth with these same effects
(:mod:`besdrake.tasks.pick_and_place.lab`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from besdrake.sim.effects import Effect, Param, RolloutSetup, register_effect


@dataclass(kw_only=True)
class PickPlaceSetup(RolloutSetup):
    """A pick-and-place rollout's setup: ``box_offset`` (dx m, dy m, dyaw rad; world frame) of the box's true start
    from its perceived one on the shelf; ``box_mass_delta`` (kg) added to the box model's mass;
    ``pad_friction_scale``: factor on the finger pads' friction coefficient (1: as modelled)."""

    box_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    box_mass_delta: float = 0.0
    pad_friction_scale: float = 1.0


@register_effect
class BoxPoseOffset(Effect):
    """Perceived-vs-true box pose: the box stands (x, y) m and yaw rad away (world frame) from where perception
    (the scenario's ``box_start`` frame) puts it, which the plan was made for.

    A camera calibration error or a box pushed aside after it was seen. The gripper closes where the box was
    perceived: an offset along the approach moves the grasp point on the box and the box's final pose with it (turned
    by the arm's turn from the shelf to the table); one across the approach is partly centred by the closing fingers
    (the first pad to touch pushes the box), a yaw turns the box in the grasp. Applied where the box is placed at
    the start of the rollout (initial state); no rebuild.
    """

    name = "box_pose_offset"
    applied_via = "initial state"
    params = {
        "x": Param(0.0, -0.05, 0.05, "m", "true minus perceived box position along world x"),
        "y": Param(0.0, -0.05, 0.05, "m", "true minus perceived box position along world y"),
        "yaw": Param(0.0, -0.3, 0.3, "rad", "true minus perceived box yaw about the vertical"),
    }

    def apply(self, setup, values):
        setup.box_offset = np.asarray(setup.box_offset, float) + np.array([values["x"], values["y"], values["yaw"]])


@register_effect
class BoxMass(Effect):
    """Box mass: the box weighs ``delta`` kg more (or less) than its model.

    A heavier box needs more grip (friction holds it: it slips sooner when the pads' friction is low) and loads the
    arm while carried: the servos, whose gravity feed-forward knows the arm only, sag a little more under it (joint
    tracking during the carry). Applied to the box body's mass in the Context; no rebuild.
    """

    name = "box_mass"
    params = {"delta": Param(0.0, -0.15, 1.0, "kg", "true minus modelled box mass")}

    def apply(self, setup, values):
        setup.box_mass_delta = float(setup.box_mass_delta) + values["delta"]


@register_effect
class PadFriction(Effect):
    """Finger pad friction: the pads' Coulomb friction coefficient (static and dynamic) is ``scale`` times the
    model's (worn or dusty pads below 1, fresh rubber above).

    The box is held by friction only: with less of it the box slides down between the pads while it is lifted and
    carried (slip in the gripper), is put down lower and turned, or drops. Drake combines the pads' and the box's
    coefficients per contact (2 mu1 mu2 / (mu1 + mu2)). Applied to the pads' proximity properties in the SceneGraph's
    Context (restored at every reset); no rebuild.
    """

    name = "pad_friction"
    params = {"scale": Param(1.0, 0.01, 2.0, "1", "factor on the finger pads' friction coefficient")}

    def apply(self, setup, values):
        setup.pad_friction_scale = float(setup.pad_friction_scale) * values["scale"]


__all__ = ["PickPlaceSetup", "BoxPoseOffset", "BoxMass", "PadFriction"]
