"""What a task's reward gives policy search for one episode: a :class:`RewardBreakdown` (the reward, the distance of
the task's outcome point from its target, the limit penalty), and the goal of refinement, :data:`SUCCESS_DISTANCE`.

Tasks build their rewards on it (:meth:`besdrake.task.Task.reward`); :mod:`besdrake.search.refinement` maximises them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: The goal of refinement: touchdown within this distance (m) of the target, no limit violated.
SUCCESS_DISTANCE = 0.1


class RefinementError(ValueError):
    """Bad input to refinement: a malformed template, target, scaling or run folder."""


@dataclass
class RewardBreakdown:
    """One episode's reward and its parts (m; ``reward`` is NaN for a failed episode): the distance of the task's
    outcome point (``touchdown``, x and y in m) from the target and the limit penalty."""

    reward: float
    distance: float
    penalty: float
    touchdown: tuple[float, float] | None
    flags: list[str] = field(default_factory=list)
    message: str = ""
    #: RMS distance (m) of the outcome point over the setup's scatter where a robust check ran
    #: (:mod:`besdrake.search.refinement.robust`), else NaN
    robust_distance: float = float("nan")
    #: rollouts that robust check took (0: none ran)
    robust_rollouts: int = 0

    @property
    def failed(self) -> bool:
        return not np.isfinite(self.reward)

    @property
    def success(self) -> bool:
        """Touchdown within :data:`SUCCESS_DISTANCE` of the target and no limit violated."""
        return (not self.failed) and self.touchdown is not None and self.distance < SUCCESS_DISTANCE and self.penalty == 0.0


def failed_breakdown(message: str) -> RewardBreakdown:
    """The record of an episode that produced no rollout (NaN reward)."""
    return RewardBreakdown(np.nan, np.nan, np.nan, None, ["failed"], message)
