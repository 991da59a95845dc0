"""Minimum regret search (Metzen 2016).

Entropy search rewards any information about *where* the maximum is; minimum regret search rewards
only information that lowers the *expected simple regret* of the final recommendation. With the
recommendation being the representer with the highest posterior mean (the minimiser of expected
regret over the representers), the expected regret is ``E[max_i f_i] - max_i m_i``; the acquisition
value of a candidate is how much a fantasised observation there lowers it, in expectation over the
outcome. The Monte-Carlo machinery (representer points, joint samples, pathwise fantasies) is shared
with entropy search, see :mod:`besdrake.search.entropy_search` for its approximations.
"""

from __future__ import annotations

import numpy as np

from .entropy_search import RepresenterModel
from .gp import GaussianProcess

__all__ = ["minimum_regret_search"]


def minimum_regret_search(
    gp: GaussianProcess,
    representers: np.ndarray,
    candidates: np.ndarray,
    rng: np.random.Generator,
    n_samples: int = 256,
    n_fantasies: int = 5,
) -> np.ndarray:
    """Expected reduction of the expected regret (reward units) at ``candidates``; larger is better."""
    return RepresenterModel(gp, representers, rng, n_samples, n_fantasies).regret_reduction(candidates)
