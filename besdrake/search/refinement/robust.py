"""Robust refinement: a candidate near the goal is simulated again under the lab's trial-to-trial scatter of the task's
setup (:meth:`besdrake.task.Task.scatter_effects`, e.g. where the ball sits in the scoop), and its reward becomes the
root-mean-square distance of the outcome point from the target over that scatter (issue 27).

Why: a plan that hits the target in simulation can sit on a cliff, where a millimetre of placement sends the ball
elsewhere; in the lab such a plan lands on the target in some repetitions and far off in others. The nominal
distance cannot see that; the RMS distance over the scatter's quadrature can (``E|p - target|^2`` is the squared
distance of the mean outcome plus the outcome's variance, so the reward is smooth near the goal and prefers a plan
whose outcome stays put). Only candidates within :attr:`RobustCheck.radius` of the target and within every limit are
checked, so the price in rollouts is paid near the goal only (measured: :mod:`besdrake.tasks.throwing`'s
``REFINEMENT.md``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from besdrake.search.reward import RewardBreakdown
from besdrake.search.refinement.settings import RefinementError

#: Candidates whose nominal outcome lands within this distance (m) of the target are checked.
ROBUST_RADIUS = 0.3
#: Distance (m) counted for a perturbed rollout without an outcome point (failed simulation, no distance).
MISS_DISTANCE = 1.0


@dataclass
class RobustCheck:
    """The setup's scatter as ``effects`` (one mapping per perturbed rollout; the nominal setup is not among them) and
    ``weights`` (the nominal's first, then one per effect, summing to 1): a quadrature over the scatter."""

    effects: Sequence[dict[str, Any]]
    weights: Sequence[float]
    radius: float = ROBUST_RADIUS
    miss_distance: float = MISS_DISTANCE

    def __post_init__(self) -> None:
        self.effects = [dict(e) for e in self.effects]
        w = np.asarray(self.weights, dtype=float).ravel()
        if not self.effects or w.size != len(self.effects) + 1 or not np.isfinite(w).all() or (w < 0).any() or abs(w.sum() - 1.0) > 1e-9:
            raise RefinementError(f"a robust check needs >= 1 effect and one weight more (the nominal's first), "
                                  f"non-negative and summing to 1; got {len(self.effects)} effects, weights {w.tolist()}")
        self.weights = w
        for name in ("radius", "miss_distance"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v > 0):
                raise RefinementError(f"{name} must be a finite number > 0 m, got {v!r}")
            setattr(self, name, v)

    @classmethod
    def from_task(cls, task, scenario, sd: float, **kwargs: Any) -> "RobustCheck | None":
        """The check over ``task.scatter_effects(scenario, sd)`` (None where the task models no scatter)."""
        effects, weights = task.scatter_effects(scenario, sd)
        if len(effects) < 2:
            return None
        return cls(list(effects[1:]), np.asarray(weights, dtype=float), **kwargs)

    @property
    def n_rollouts(self) -> int:
        """Extra rollouts per checked candidate."""
        return len(self.effects)

    def needs(self, r: RewardBreakdown) -> bool:
        """Whether the nominal record ``r`` is near enough the goal (within every limit) to be checked."""
        return (not r.failed) and r.touchdown is not None and r.penalty == 0.0 and r.distance < self.radius

    def combine(self, nominal: RewardBreakdown, perturbed: Sequence[RewardBreakdown]) -> RewardBreakdown:
        """The nominal record with the reward ``-RMS distance - penalty`` over the quadrature and the RMS distance
        kept (``robust_distance``)."""
        d = np.array([nominal.distance] + [p.distance if np.isfinite(p.distance) else self.miss_distance for p in perturbed])
        rms = float(np.sqrt(self.weights @ d**2))
        return RewardBreakdown(-rms - nominal.penalty, nominal.distance, nominal.penalty, nominal.touchdown, list(nominal.flags),
                               nominal.message, robust_distance=rms)

    def to_dict(self) -> dict[str, Any]:
        return {"effects": [dict(e) for e in self.effects], "weights": [float(v) for v in self.weights],
                "radius": self.radius, "miss_distance": self.miss_distance}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "RobustCheck":
        try:
            return cls(d["effects"], d["weights"], float(d["radius"]), float(d["miss_distance"]))
        except (KeyError, TypeError, ValueError) as err:
            raise RefinementError(f"bad robust check {d!r}: {err}") from err
