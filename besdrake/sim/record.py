"""Self-contained meshcat HTML replays of a rollout (offline, no browser needed).

The rollout of the scenario's task is simulated first; the task then poses the Diagram kinematically frame by frame
into meshcat's recording (:meth:`besdrake.task.Task.record_replay`), and ``Meshcat.StaticHtml()`` writes one HTML
file that plays the animation anywhere.
"""

from __future__ import annotations

import gc
from pathlib import Path
from typing import Any

from besdrake._io import write_text as _atomic_write_text
from besdrake.plan import MotionPlan
from besdrake.sim.scenario import Scenario


def record_html(plan: MotionPlan, out: str | Path, scenario: Scenario | str = "nominal", effects: dict | None = None, fps: float = 60.0, limits: str = "raise", host: str = "localhost") -> tuple[Path, Any]:
    """Simulate ``plan`` and write the replay to ``out`` (.html); returns (path, the task's outcome). The meshcat
    server that records it listens on ``host`` only (localhost by default; "*" would open it to the network)."""
    from pydrake.geometry import Meshcat, MeshcatParams

    from besdrake.sim.rollout import Rollout
    from besdrake.task import get_task

    meshcat = Meshcat(MeshcatParams(host=host))
    sim = Rollout(scenario, meshcat=meshcat)
    outcome = sim.rollout(plan, effects=effects, limits=limits)
    get_task(sim.scenario.task).record_replay(sim, plan, outcome, meshcat, fps)
    html = meshcat.StaticHtml()
    # Drake's Meshcat must be destroyed on the thread that made it: free the Diagram that holds it now, in this
    # thread, rather than leave the cycle to a garbage collection that may run in a worker pool's thread (abort).
    del sim
    gc.collect()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    _atomic_write_text(out, html)
    return out, outcome
