"""Robust refinement: a candidate near the goal is simulated again under the lab's trial-to-trial scatter of the task's
setup (:meth:`besdrake.task.Task.scatter_effects`, e.g. where an object is put), and its reward becomes the
root-mean-square distance of the outcome point from the target over that scatter (issue 27).

Why: a plan that hits the target in simulation can sit on a cliff, where a millimetre of setup sends the outcome
elsewhere; in the lab such a plan lands on the target in some repetitions and far off in others. The nominal
distance cannot see that; the RMS distance over the scatter's quadrature can (``E|p - target|^2`` is the squared
distance of the mean outcome plus the outcome's variance, so the reward is smooth near the goal and prefers a plan
whose outcome stays put). Only candidates within :attr:`RobustCheck.radius` of the target and within every limit are
checked, so the price in rollouts is paid near the goal only, and a check *probes* first: the two setups farthest
apart (e.g. two opposite corners of the quadrature) are simulated, and only where one of them moves the outcome
point by :attr:`RobustCheck.probe_tolerance` or more are the other setups simulated too (elsewhere they count as
landing where the nominal does). Optionally a check is spent only where it can matter (:attr:`RobustCheck.frontier`,
e.g. :data:`FRONTIER_MARGIN`): on a candidate whose nominal distance could make it the run's best so far (within the
frontier margin of the best objective of the episodes before its batch); the others are rewarded by their nominal
distance (no robust distance recorded). The run's best, the plan it returns and the stop on success are then still
judged over the scatter, at about half the check rollouts (learn's default in session 39 only, an option since: see the task's notes). Measured on a
task: the notes beside it (``besdrake/tasks/<name>/REFINEMENT.md``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from besdrake.search.reward import RewardBreakdown
from besdrake.search.refinement.settings import RefinementError

#: Candidates whose nominal outcome lands within this distance (m) of the target are checked.
ROBUST_RADIUS = 0.2
#: Distance (m) counted for a perturbed rollout without an outcome point (failed simulation, no distance).
MISS_DISTANCE = 1.0
#: A probe that moves the outcome point less than this (m) from the nominal's counts as "stays put".
PROBE_TOLERANCE = 0.01
#: With a frontier, a candidate is checked only where its nominal distance is below the run's best objective so far plus
#: this (m): the probes' tolerance, so that a candidate whose scatter could bring it below the best is not missed.
FRONTIER_MARGIN = PROBE_TOLERANCE


@dataclass
class RobustCheck:
    """The setup's scatter as ``effects`` (one mapping per perturbed rollout; the nominal setup is not among them) and
    ``weights`` (the nominal's first, then one per effect, summing to 1): a quadrature over the scatter."""

    effects: Sequence[dict[str, Any]]
    weights: Sequence[float]
    radius: float = ROBUST_RADIUS
    miss_distance: float = MISS_DISTANCE
    #: m; None: no probing (every setup simulated at once)
    probe_tolerance: float | None = PROBE_TOLERANCE
    #: m; None: every candidate within the radius is checked, not only those that could become the run's best
    frontier: float | None = None

    def __post_init__(self) -> None:
        self.effects = [dict(e) for e in self.effects]
        w = np.asarray(self.weights, dtype=float).ravel()
        if not self.effects or w.size != len(self.effects) + 1 or not np.isfinite(w).all() or (w < 0).any() or abs(w.sum() - 1.0) > 1e-9:
            raise RefinementError(f"a robust check needs >= 1 effect and one weight more (the nominal's first), "
                                  f"non-negative and summing to 1; got {len(self.effects)} effects, weights {w.tolist()}")
        self.weights = w
        names = ("radius", "miss_distance") + (("probe_tolerance",) if self.probe_tolerance is not None else ()) + (
            ("frontier",) if self.frontier is not None else ())
        for name in names:
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
        """Extra rollouts of a full check."""
        return len(self.effects)

    def probes(self) -> list[int]:
        """Indices of the setups simulated first: the two whose numeric parameters lie farthest apart (all of them
        without probing or with fewer than three setups)."""
        if self.probe_tolerance is None or len(self.effects) < 3:
            return list(range(len(self.effects)))
        v = np.array([_numbers(e) for e in self.effects])
        d = np.linalg.norm(v[:, None, :] - v[None, :, :], axis=2)
        i, j = np.unravel_index(int(np.argmax(d)), d.shape)
        return sorted({int(i), int(j)})

    def stays_put(self, nominal: RewardBreakdown, probed: Sequence[RewardBreakdown]) -> bool:
        """Whether every probe's outcome point lies within :attr:`probe_tolerance` of the nominal's (so the other setups
        are not simulated)."""
        if self.probe_tolerance is None or len(probed) == len(self.effects):
            return False
        t0 = np.asarray(nominal.touchdown, dtype=float)
        return all(p.touchdown is not None and np.linalg.norm(np.asarray(p.touchdown, dtype=float) - t0) < self.probe_tolerance
                   for p in probed)

    def needs(self, r: RewardBreakdown) -> bool:
        """Whether the nominal record ``r`` is near enough the goal (within every limit) to be checked."""
        return (not r.failed) and r.touchdown is not None and r.penalty == 0.0 and r.distance < self.radius

    def on_frontier(self, r: RewardBreakdown, best_objective: float) -> bool:
        """Whether ``r``'s nominal distance could make it the run's best (``best_objective``: m, minus the best reward of
        the episodes before; ``inf`` where there are none), so that its check can matter; always without a frontier."""
        return self.frontier is None or r.distance < best_objective + self.frontier

    def combine(self, nominal: RewardBreakdown, perturbed: Sequence[RewardBreakdown | None]) -> RewardBreakdown:
        """The nominal record with the reward ``-RMS distance - penalty`` over the quadrature and the RMS distance
        kept (``robust_distance``); ``perturbed``: one record per setup, None for one not simulated (it counts as the
        nominal), and the number of rollouts spent (``robust_rollouts``)."""
        d = np.array([nominal.distance] + [nominal.distance if p is None else p.distance if np.isfinite(p.distance)
                                           else self.miss_distance for p in perturbed])
        rms = float(np.sqrt(self.weights @ d**2))
        return RewardBreakdown(-rms - nominal.penalty, nominal.distance, nominal.penalty, nominal.touchdown, list(nominal.flags),
                               nominal.message, robust_distance=rms, robust_rollouts=sum(p is not None for p in perturbed))

    def to_dict(self) -> dict[str, Any]:
        return {"effects": [dict(e) for e in self.effects], "weights": [float(v) for v in self.weights],
                "radius": self.radius, "miss_distance": self.miss_distance, "probe_tolerance": self.probe_tolerance} | (
                    {"frontier": self.frontier} if self.frontier is not None else {})

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "RobustCheck":
        try:
            tol, front = d.get("probe_tolerance"), d.get("frontier")  # no frontier recorded: every candidate was checked
            return cls(d["effects"], d["weights"], float(d["radius"]), float(d["miss_distance"]), None if tol is None else float(tol),
                       None if front is None else float(front))
        except (KeyError, TypeError, ValueError) as err:
            raise RefinementError(f"bad robust check {d!r}: {err}") from err


def _numbers(effect: dict[str, Any]) -> list[float]:
    """The numeric parameters of an effect mapping (``{name: {param: value}}``), in a fixed order."""
    return [float(v) for name in sorted(effect) for _, v in sorted(dict(effect[name]).items())]
