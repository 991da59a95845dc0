"""The throw's replay frames: the arm as measured while simulated (then as commanded), the ball along the outcome's path
(simulated, then its free flight to touchdown) and a marker at the touchdown, recorded into meshcat
(:func:`besdrake.sim.record.record_html` writes the HTML)."""

from __future__ import annotations

import numpy as np

from besdrake.plan import MotionPlan


def record_throw(sim, plan: MotionPlan, outcome, meshcat, fps: float) -> None:
    """Pose ``sim``'s Diagram kinematically every ``1/fps`` s and record the frames in ``meshcat``."""
    from pydrake.geometry import Rgba, Sphere
    from pydrake.math import RigidTransform

    h = sim.handles
    plant, ctx = h.plant, sim.context
    pctx = sim.plant_context
    vis = h.visualizer
    t_end = float(outcome.ball_t[-1]) if outcome.ball_t.size else plan.duration
    t_end = max(t_end, min(plan.duration, t_end + 0.3))
    if outcome.touchdown is not None:
        meshcat.SetObject("/target/touchdown", Sphere(0.02), Rgba(0.9, 0.1, 0.1, 1.0))
        meshcat.SetTransform("/target/touchdown", RigidTransform([outcome.touchdown[0], outcome.touchdown[1], 0.0]))
    vis.StartRecording(set_transforms_while_recording=False)
    t_meas = outcome.joint_t
    for t in np.arange(0.0, t_end + 1e-9, 1.0 / fps):
        if t_meas.size and t <= t_meas[-1]:
            q = np.array([np.interp(t, t_meas, outcome.q_measured[:, j]) for j in range(outcome.q_measured.shape[1])])
        else:
            q = plan.sample(np.array([t]))[0]
        plant.SetPositions(pctx, h.arm, q)
        if outcome.ball_t.size:
            p = np.array([np.interp(t, outcome.ball_t, outcome.ball_path[:, k]) for k in range(3)])
            plant.SetFreeBodyPose(pctx, h.scene.ball_body, RigidTransform(p))
        ctx.SetTime(float(t))
        h.diagram.ForcedPublish(ctx)
    vis.StopRecording()
    vis.PublishRecording()
