"""Self-contained meshcat HTML replays of a rollout (offline, no browser needed).

The rollout is simulated first (the simulation stops at release); the replay then poses the Diagram
kinematically frame by frame: the measured joint angles while simulated, then the commanded plan, and the
ball along the Outcome's path (simulated, then its free flight to touchdown). MeshcatVisualizer records the
frames and ``Meshcat.StaticHtml()`` writes one HTML file that plays the animation anywhere.
"""

from __future__ import annotations

import gc

from pathlib import Path

from typing import Any

import numpy as np

from besdrake._io import write_text as _atomic_write_text
from besdrake.plan import MotionPlan
from besdrake.sim.scenario import Scenario


def record_html(plan: MotionPlan, out: str | Path, scenario: Scenario | str = "nominal", effects: dict | None = None, fps: float = 60.0, limits: str = "raise", host: str = "localhost") -> tuple[Path, Any]:
    """Simulate ``plan`` and write the replay to ``out`` (.html); returns (path, Outcome). The meshcat server
    that records it listens on ``host`` only (localhost by default; "*" would open it to the network)."""
    from pydrake.geometry import Meshcat, MeshcatParams, Rgba, Sphere
    from pydrake.math import RigidTransform

    from besdrake.sim.rollout import Rollout

    meshcat = Meshcat(MeshcatParams(host=host))
    sim = Rollout(scenario, meshcat=meshcat)
    outcome = sim.rollout(plan, effects=effects, limits=limits)
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
            plant.SetFreeBodyPose(pctx, h.ball_body, RigidTransform(p))
        ctx.SetTime(float(t))
        h.diagram.ForcedPublish(ctx)
    vis.StopRecording()
    vis.PublishRecording()
    html = meshcat.StaticHtml()
    # Drake's Meshcat must be destroyed on the thread that made it: free the Diagram that holds it now, in this
    # thread, rather than leave the cycle to a garbage collection that may run in a worker pool's thread (abort).
    del vis, h, plant, ctx, pctx, sim
    gc.collect()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    _atomic_write_text(out, html)
    return out, outcome
