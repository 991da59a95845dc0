"""Bayesian optimization for contextual policy search (BO-CPS, Metzen 2015).

One GP models the reward over the joint space ``(context, params)`` (inputs ordered context first).
For the context ``s`` of an episode, :meth:`BOCPS.ask` chooses the parameters by maximising an
acquisition restricted to that context:

* ``"ucb"``: ``mean + kappa * std`` at ``(s, theta)``;
* ``"es"``: contextual entropy search: the expected information gain about the maximisers
  ``theta*(s_i)`` of a set of representative contexts ``s_i`` (the episode's context plus
  ``n_rep_contexts`` fixed quasi-random contexts), summed over them. One ``p_max`` distribution per
  context over ``n_representers`` representer parameters each; the Monte-Carlo machinery and its
  approximations are those of :mod:`besdrake.search.entropy_search`.

The upper-level policy :meth:`BOCPS.policy` is the maximiser of the posterior mean for the given
context (no exploration, no randomness), so a trained optimizer is a behaviour template:
``state_dict`` holds the data, the kernel hyperparameters and the generator state.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.stats import qmc

from .acquisition import maximize_on_box, upper_confidence_bound
from .base import ContextualOptimizer
from .entropy_search import RepresenterModel, select_representers
from .gp import DEFAULT_LENGTH_SCALE_BOUNDS, GaussianProcess, GPEpisodes, check_bounds, single_threaded

__all__ = ["BOCPS", "CONTEXTUAL_ACQUISITIONS"]

CONTEXTUAL_ACQUISITIONS = ("ucb", "es")
DEFAULT_LENGTH_SCALE_MIN = DEFAULT_LENGTH_SCALE_BOUNDS[0]


class BOCPS(GPEpisodes, ContextualOptimizer):
    """BO-CPS with UCB or contextual entropy-search acquisition.

    Parameters
    ----------
    context_bounds, param_bounds:
        Boxes of contexts ``(n_context, 2)`` and parameters ``(n_params, 2)``, SI units.
    acquisition:
        ``"ucb"`` or ``"es"``.
    rng:
        The only source of randomness.
    n_initial:
        Episodes with uniform random parameters before the model is used (default
        ``n_params + n_context + 2``).
    kappa:
        UCB exploration weight (UCB acquisition; also ranks ES candidates).
    n_rep_contexts, n_representers, n_samples, n_fantasies, pool_size:
        Contextual entropy search: representative contexts, representer parameters per context,
        Monte-Carlo samples, fantasy nodes, random parameter pool per context.
    nu, n_restarts:
        GP kernel smoothness and hyperparameter restarts.
    prior_mean:
        Optional prior knowledge of the reward: ``{"type": "reach", "probe": ...}`` (a
        :class:`~besdrake.search.template_reach.ReachProbe` as a dict); the GP then models the reward minus
        the prior (:class:`~besdrake.search.template_reach.PriorMeanGP`). Kept in the state.
    length_scale_min:
        Lower bound of the GP's length scales on the unit box (default: :class:`~besdrake.search.gp.GaussianProcess`'s,
        0.01). Kept in the state (a state without it restores the default).
    """

    def __init__(
        self,
        context_bounds: Any,
        param_bounds: Any,
        acquisition: str = "es",
        rng: np.random.Generator | None = None,
        n_initial: int | None = None,
        kappa: float = 2.0,
        n_rep_contexts: int = 8,
        n_representers: int = 16,
        n_samples: int = 256,
        n_fantasies: int = 5,
        pool_size: int = 200,
        nu: float = 2.5,
        n_restarts: int = 1,
        prior_mean: dict[str, Any] | None = None,
        length_scale_min: float = DEFAULT_LENGTH_SCALE_MIN,
    ) -> None:
        self.context_bounds = check_bounds(context_bounds, "context_bounds")
        self.param_bounds = check_bounds(param_bounds, "param_bounds")
        self.n_context, self.n_params = self.context_bounds.shape[0], self.param_bounds.shape[0]
        if acquisition not in CONTEXTUAL_ACQUISITIONS:
            raise ValueError(f"unknown acquisition {acquisition!r}; choose one of {CONTEXTUAL_ACQUISITIONS}")
        self.acquisition = acquisition
        self.rng = rng if rng is not None else np.random.default_rng()
        self.n_initial = int(n_initial) if n_initial is not None else self.n_params + self.n_context + 2
        if self.n_initial < 1:
            raise ValueError(f"n_initial must be >= 1, got {self.n_initial}")
        self.kappa = float(kappa)
        self.n_rep_contexts, self.n_representers = int(n_rep_contexts), int(n_representers)
        self.n_samples, self.n_fantasies, self.pool_size = int(n_samples), int(n_fantasies), int(pool_size)
        self.length_scale_min = float(length_scale_min)
        if not 0.0 < self.length_scale_min < DEFAULT_LENGTH_SCALE_BOUNDS[1]:
            raise ValueError(f"length_scale_min must be within (0, {DEFAULT_LENGTH_SCALE_BOUNDS[1]:g}) on the unit box, "
                             f"got {length_scale_min!r}")
        self.gp = GaussianProcess(np.vstack([self.context_bounds, self.param_bounds]), nu=nu, n_restarts=n_restarts,
                                  length_scale_bounds=(self.length_scale_min, DEFAULT_LENGTH_SCALE_BOUNDS[1]),
                                  seed=int(self.rng.integers(2**31 - 1)))
        self.prior_mean = prior_mean
        self._wrap_prior()
        self.rep_contexts = self._scale(self.context_bounds,
                                        qmc.Halton(self.n_context, seed=self.rng).random(self.n_rep_contexts))
        # Deterministic parameter grid for the (randomness-free) policy.
        self._policy_grid = self._scale(self.param_bounds,
                                        qmc.Sobol(self.n_params, scramble=False).random(256))
        self._init_episodes(self.n_context + self.n_params)

    # ------------------------------------------------------------------ helpers
    def _wrap_prior(self) -> None:
        """Model the reward minus ``prior_mean`` (no-op without one)."""
        if self.prior_mean is None:
            return
        from .template_reach import prior_from_dict, PriorMeanGP

        self.gp = PriorMeanGP.wrap(self.gp, prior_from_dict(self.prior_mean, self.n_context))

    @staticmethod
    def _scale(bounds: np.ndarray, unit: np.ndarray) -> np.ndarray:
        return bounds[:, 0] + unit * (bounds[:, 1] - bounds[:, 0])

    def _check_context(self, context: Any) -> np.ndarray:
        context = np.asarray(context, dtype=float).ravel()
        if context.shape != (self.n_context,):
            raise ValueError(f"context must have {self.n_context} values, got shape {context.shape}")
        if not np.isfinite(context).all():
            raise ValueError(f"context must be finite, got {context.tolist()}")
        return context

    def _joint(self, context: np.ndarray, params: np.ndarray) -> np.ndarray:
        params = np.atleast_2d(params)
        return np.hstack([np.broadcast_to(context, (len(params), self.n_context)), params])

    def _random_params(self, n: int) -> np.ndarray:
        return self.rng.uniform(self.param_bounds[:, 0], self.param_bounds[:, 1], size=(n, self.n_params))

    @property
    def n_episodes(self) -> int:
        return int(self.y.size)

    # ------------------------------------------------------------------ ask / tell
    @single_threaded
    def ask(self, context: np.ndarray) -> np.ndarray:
        """Parameters to try in ``context``, shape ``(n_params,)``."""
        context = self._check_context(context)
        if self.y.size < self.n_initial:
            return self._random_params(1)[0]
        self._fit()
        if self.acquisition == "ucb":
            theta, _ = maximize_on_box(
                lambda P: upper_confidence_bound(self.gp, self._joint(context, P), self.kappa),
                self.param_bounds, self.rng, self.pool_size, extra=self.X[:, self.n_context:])
            return theta
        return self._ask_entropy_search(context)

    def _representers(self, contexts: np.ndarray) -> np.ndarray:
        """Representer points ``(n_contexts, n_representers, n_context + n_params)``, EI-weighted per context."""
        groups = []
        for s in contexts:
            pool = self._joint(s, np.vstack([self._random_params(self.pool_size), self.policy_candidates(s)]))
            groups.append(select_representers(self.gp, pool, self.n_representers, self.rng))
        return np.stack(groups)

    def policy_candidates(self, context: np.ndarray) -> np.ndarray:
        """Parameters worth considering for ``context``: the posterior-mean maximiser (cheap estimate)."""
        grid = self._joint(context, self._policy_grid)
        return self._policy_grid[[int(np.argmax(self.gp.predict(grid)))]]

    def _ask_entropy_search(self, context: np.ndarray) -> np.ndarray:
        contexts = np.vstack([context[None, :], self.rep_contexts])
        representers = self._representers(contexts)
        model = RepresenterModel(self.gp, representers, self.rng, self.n_samples, self.n_fantasies)
        pool = self._random_params(self.pool_size)
        ucb = upper_confidence_bound(self.gp, self._joint(context, pool), self.kappa)
        params = np.vstack([representers[0, :, self.n_context:], pool[np.argsort(-ucb)[:20]], self._random_params(20)])
        gains = model.information_gain(self._joint(context, params))
        return params[int(np.argmax(gains))].copy()

    def tell(self, context: np.ndarray, params: np.ndarray, reward: float) -> None:
        """Report the reward of ``params`` in ``context``; NaN/inf is a failed episode (penalised)."""
        context = self._check_context(context)
        params = np.asarray(params, dtype=float).ravel()
        if params.shape != (self.n_params,):
            raise ValueError(f"params must have {self.n_params} values, got shape {params.shape}")
        if not np.isfinite(params).all():
            raise ValueError(f"params must be finite, got {params.tolist()}")
        reward_arr = np.asarray(reward, dtype=float).ravel()
        if reward_arr.size != 1:
            raise ValueError(f"reward must be one number, got shape {np.shape(reward)}")
        self._add_episodes(np.concatenate([context, params])[None, :], reward_arr)

    # ------------------------------------------------------------------ policy
    @single_threaded
    def policy(self, context: np.ndarray) -> np.ndarray:
        """Posterior-mean maximiser over the parameters for ``context`` (deterministic)."""
        context = self._check_context(context)
        if not self.y.size:
            return self.param_bounds.mean(axis=1)
        self._fit()
        theta, _ = maximize_on_box(lambda P: self.gp.predict(self._joint(context, P)), self.param_bounds, None,
                                   extra=np.vstack([self._policy_grid, self.X[:, self.n_context:]]), n_local=1)
        return theta

    def expected_reward(self, context: np.ndarray, params: np.ndarray) -> tuple[float, float]:
        """Posterior mean and standard deviation of the reward of ``params`` in ``context`` (on the GP's scale: saturated
        where a reach prior saturates it, :class:`~besdrake.search.template_reach.ReachPrior`)."""
        context = self._check_context(context)
        if not self.y.size:
            raise RuntimeError("no episodes yet")
        self._fit()
        mean, std = self.gp.predict(self._joint(context, np.asarray(params, dtype=float).ravel()), return_std=True)
        return float(mean[0]), float(std[0])

    # ------------------------------------------------------------------ persistence
    def _settings(self) -> dict[str, Any]:
        return {
            "acquisition": self.acquisition, "n_initial": self.n_initial, "kappa": self.kappa,
            "n_rep_contexts": self.n_rep_contexts, "n_representers": self.n_representers,
            "n_samples": self.n_samples, "n_fantasies": self.n_fantasies, "pool_size": self.pool_size,
            "nu": self.gp.nu, "n_restarts": self.gp.n_restarts, "prior_mean": self.prior_mean,
            "length_scale_min": self.length_scale_min,
        }

    def state_dict(self) -> dict[str, Any]:
        return {
            "type": type(self).__name__,
            "context_bounds": self.context_bounds.copy(),
            "param_bounds": self.param_bounds.copy(),
            "settings": self._settings(),
            "rep_contexts": self.rep_contexts.copy(),
            **self._episodes_state(),
        }

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "BOCPS":
        opt = cls(state["context_bounds"], state["param_bounds"], **state["settings"])
        opt.rep_contexts = np.asarray(state["rep_contexts"], dtype=float).reshape(-1, opt.n_context)
        opt._restore_episodes(state)
        opt._wrap_prior()
        return opt
