"""Active contextual entropy search (ACES, Metzen 2015).

When the learner may choose the context of the next episode, ACES picks the pair
``(context, params)`` with the largest expected information gain about the maximisers
``theta*(s_i)`` of the representative contexts ``s_i`` (summed over them), i.e. the episode that
teaches the most about the whole upper-level policy. :meth:`ACES.select_context` returns the
context of that pair and remembers its parameters; the following :meth:`ACES.ask` with that
context returns them. Asked for any other context, ACES behaves like BO-CPS with entropy search.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .bocps import BOCPS
from .entropy_search import RepresenterModel
from .gp import check_bounds, single_threaded
from .acquisition import upper_confidence_bound

__all__ = ["ACES"]


class ACES(BOCPS):
    """BO-CPS with entropy search and active context selection.

    ``n_context_candidates`` random contexts (plus the representative ones) are scored, each with
    its best UCB parameters among a small random pool and one random parameter vector; the four most
    probable maximisers of every representative context are scored as well.
    """

    def __init__(self, context_bounds: Any, param_bounds: Any, rng: np.random.Generator | None = None,
                 n_context_candidates: int = 30, **kwargs: Any) -> None:
        kwargs.pop("acquisition", None)
        super().__init__(context_bounds, param_bounds, acquisition="es", rng=rng, **kwargs)
        self.n_context_candidates = int(n_context_candidates)
        self._pending: tuple[np.ndarray, np.ndarray] | None = None

    @single_threaded
    def select_context(self, bounds: np.ndarray | None = None) -> np.ndarray:
        """The most informative context within ``bounds`` (default: the context bounds)."""
        bounds = self.context_bounds if bounds is None else check_bounds(bounds, "bounds")
        if bounds.shape != self.context_bounds.shape:
            raise ValueError(f"bounds must have shape {self.context_bounds.shape}, got {bounds.shape}")
        low, high = bounds[:, 0], bounds[:, 1]
        if self.y.size < self.n_initial:
            context = self.rng.uniform(low, high)
            self._pending = None
            return context
        self._fit()
        representers = self._representers(self.rep_contexts)
        model = RepresenterModel(self.gp, representers, self.rng, self.n_samples, self.n_fantasies)
        contexts = np.vstack([self.rng.uniform(low, high, size=(self.n_context_candidates, self.n_context)),
                              np.clip(self.rep_contexts, low, high)])
        pairs = []
        for s in contexts:
            pool = self._random_params(50)
            ucb = upper_confidence_bound(self.gp, self._joint(s, pool), self.kappa)
            pairs.append(self._joint(s, pool[[int(np.argmax(ucb))]]))
            pairs.append(self._joint(s, self._random_params(1)))
        # per representative context, its most probable maximisers (top 4 of p_max)
        top = np.argsort(-model.p_max(), axis=1)[:, :4]
        flat = np.take_along_axis(representers, top[:, :, None], axis=1).reshape(-1, representers.shape[-1])
        inside = np.all((flat[:, :self.n_context] >= low) & (flat[:, :self.n_context] <= high), axis=1)
        candidates = np.vstack(pairs + [flat[inside]])
        gains = model.information_gain(candidates)
        best = candidates[int(np.argmax(gains))]
        self._pending = (best[:self.n_context].copy(), best[self.n_context:].copy())
        return self._pending[0].copy()

    def ask(self, context: np.ndarray) -> np.ndarray:
        """The parameters chosen with the context by :meth:`select_context`, else BO-CPS/ES."""
        context = self._check_context(context)
        if self._pending is not None and np.allclose(context, self._pending[0]):
            params = self._pending[1].copy()
            self._pending = None
            return params
        return super().ask(context)

    def _settings(self) -> dict[str, Any]:
        settings = super()._settings()
        settings.pop("acquisition")
        settings["n_context_candidates"] = self.n_context_candidates
        return settings

    def state_dict(self) -> dict[str, Any]:
        state = super().state_dict()
        state["pending"] = None if self._pending is None else np.concatenate(self._pending)
        return state

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "ACES":
        opt = super().from_state(state)
        pending = state.get("pending")
        if pending is not None:
            pending = np.asarray(pending, dtype=float).ravel()
            opt._pending = (pending[:opt.n_context], pending[opt.n_context:])
        return opt
