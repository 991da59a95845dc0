"""The grasp's replay: the arm, gripper and box as simulated (from the rollout's state log), a marker on the place,
recorded into meshcat (:func:`besdrake.sim.record.record_html` writes the self-contained HTML)."""

from __future__ import annotations

import numpy as np

from besdrake.plan import MotionPlan


def record_grasp(rollout, plan: MotionPlan, outcome, meshcat, fps: float) -> None:
    """Pose ``rollout``'s Diagram every ``1/fps`` s as its last simulation ran and record the frames in ``meshcat``."""
    from pydrake.geometry import Cylinder, Rgba
    from pydrake.math import RigidTransform

    h = rollout.h
    if h.visualizer is None:
        raise ValueError("the rollout was built without meshcat: no replay to record")
    place = h.place_target.translation()
    meshcat.SetObject("/target/place", Cylinder(0.03, 0.002), Rgba(0.1, 0.7, 0.2, 0.6))
    meshcat.SetTransform("/target/place", RigidTransform(place + [0.0, 0.0, 0.001]))
    ts = np.asarray(rollout.log.sample_times())
    xs = np.asarray(rollout.log.data()).T
    nq = h.plant.num_positions()
    h.visualizer.StartRecording(set_transforms_while_recording=False)
    for t in np.arange(0.0, float(ts[-1]) + 1e-9, 1.0 / fps) if ts.size else []:
        k = min(int(np.searchsorted(ts, t)), len(ts) - 1)
        h.plant.SetPositions(rollout.plant_context, xs[k, :nq])
        rollout.context.SetTime(float(t))
        h.diagram.ForcedPublish(rollout.context)
    h.visualizer.StopRecording()
    h.visualizer.PublishRecording()
