"""How repeatable a throw is in the lab: a plan thrown again and again against the lab's noise floor (issue 27).

:func:`lab_repeatability` throws ``plan`` ``repeats`` times in a virtual lab
(:class:`~besdrake.tasks.throwing.lab.VirtualLab`) and as often in the same lab with the ball always placed at its
habit (``ball_placement_sd = 0``). Trial ``k`` draws its random numbers from ``[seed, k]`` in both labs (the
unexplained touchdown scatter and the marker noise are the same draws), so the second lab is the *noise floor*: the
scatter the lab gives any plan, whatever the plan. The ratio of the two scatters is what a plan adds by being
sensitive to where the ball sits in the scoop (a plan on a cliff, where a millimetre sends the ball elsewhere, shows
a ratio well above 1). Scatter: the pooled per-axis SD ``sqrt((var x + var y) / 2)`` of the seen touchdowns (m), as
the lab's module docstring defines it; a trial without a seen touchdown counts in ``n_missing``.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from besdrake.plan import MotionPlan

#: The lab the repetitions run in unless told.
DEFAULT_LAB = Path(__file__).resolve().parents[2] / "diagrams" / "labs" / "default_lab.yaml"


@dataclass
class LabRepeatability:
    """Touchdowns (m, ``(repeats, 2)``, NaN where none was seen) of a plan in the lab and in its noise floor."""

    touchdowns: np.ndarray
    floor_touchdowns: np.ndarray

    @property
    def scatter(self) -> float:
        return pooled_sd(self.touchdowns)

    @property
    def floor(self) -> float:
        return pooled_sd(self.floor_touchdowns)

    @property
    def ratio(self) -> float:
        """Scatter over the noise floor (NaN where either has fewer than two touchdowns)."""
        return self.scatter / self.floor if self.floor > 0 else float("nan")

    @property
    def n_missing(self) -> int:
        return int((~np.isfinite(self.touchdowns).all(axis=1)).sum())

    def summary(self) -> dict[str, Any]:
        td = self.touchdowns[np.isfinite(self.touchdowns).all(axis=1)]
        spread = np.linalg.norm(td - np.median(td, axis=0), axis=1) if len(td) else np.zeros(0)
        return {"repeats": int(len(self.touchdowns)), "scatter_m": _num(self.scatter), "floor_m": _num(self.floor),
                "ratio": _num(self.ratio), "n_missing": self.n_missing,
                "max_from_median_m": _num(float(spread.max())) if spread.size else None,
                "mean_touchdown_m": [float(v) for v in td.mean(axis=0)] if len(td) else None}


def _num(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def pooled_sd(touchdowns: np.ndarray) -> float:
    """``sqrt((var x + var y) / 2)`` (m, sample variances) of the finite rows; NaN with fewer than two."""
    td = np.asarray(touchdowns, dtype=float).reshape(-1, 2)
    td = td[np.isfinite(td).all(axis=1)]
    if len(td) < 2:
        return float("nan")
    return float(np.sqrt(td.var(axis=0, ddof=1).mean()))


def lab_repeatability(plan: MotionPlan, lab: str | Path = DEFAULT_LAB, repeats: int = 20, seed: int = 0) -> LabRepeatability:
    """Throw ``plan`` ``repeats`` times in ``lab`` (a lab YAML path) and in its noise floor (module docstring)."""
    from besdrake.tasks.throwing.lab import VirtualLab, load_lab_config

    if int(repeats) != repeats or repeats < 2:
        raise ValueError(f"repeats must be an integer >= 2, got {repeats!r}")
    cfg = load_lab_config(lab).with_seed(seed)
    floor_cfg = copy.deepcopy(cfg)
    floor_cfg.noise.ball_placement_sd = 0.0
    out = []
    for c in (cfg, floor_cfg):
        vlab = VirtualLab(c)
        tds = []
        for k in range(int(repeats)):
            m = vlab.execute(plan, trial=k)
            tds.append(np.full(2, np.nan) if m.touchdown is None else np.asarray(m.touchdown, dtype=float)[:2])
        out.append(np.array(tds))
    return LabRepeatability(out[0], out[1])
