"""The ask/tell interface every optimizer of :mod:`besdrake.search` implements.

Conventions (shared by all optimizers, contextual or not):

* Optimizers **maximise** a reward. (``cma`` minimises; its wrapper negates.)
* ``ask()`` returns an array of shape ``(n_candidates, n_params)``; ``tell(candidates, rewards)``
  takes the same candidates back with one reward each. Sequential methods (Bayesian optimization)
  return one candidate per ``ask``.
* Randomness comes only from the ``numpy.random.Generator`` given at construction.
* A reward that is NaN or infinite is a failed episode: :func:`sanitize_rewards` replaces it by the
  worst finite reward seen so far minus a penalty, so the search goes on and nothing is lost.
* ``state_dict()`` returns JSON-serialisable data plus numpy arrays (saved with :func:`save_state`
  as ``.json`` + ``.npz``, no pickle); ``from_state`` restores an optimizer that continues exactly
  where the saved one stopped (same candidates for the same generator state).
"""

from __future__ import annotations

import json
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

FAILED_EPISODE_PENALTY = 1.0


@dataclass
class SearchResult:
    """Best parameters found and the history of a search."""

    best_params: np.ndarray
    best_reward: float
    n_evaluations: int
    rewards: np.ndarray = field(default_factory=lambda: np.zeros(0))


def sanitize_rewards(rewards: np.ndarray, worst_seen: float | None, penalty: float = FAILED_EPISODE_PENALTY) -> tuple[np.ndarray, np.ndarray]:
    """Replace non-finite rewards by ``worst finite reward - penalty``.

    Returns the cleaned rewards and a boolean mask of the failed episodes.
    """
    rewards = np.asarray(rewards, dtype=float).copy()
    failed = ~np.isfinite(rewards)
    if failed.any():
        finite = rewards[~failed]
        candidates = [v for v in (worst_seen, finite.min() if finite.size else None) if v is not None]
        worst = min(candidates) if candidates else 0.0
        rewards[failed] = worst - penalty
    return rewards, failed


def rng_state(rng: np.random.Generator) -> dict[str, Any]:
    """JSON-serialisable state of a generator."""
    return json.loads(json.dumps(rng.bit_generator.state, default=int))


def rng_from_state(state: dict[str, Any]) -> np.random.Generator:
    bit_generator = getattr(np.random, state["bit_generator"])()
    bit_generator.state = state
    return np.random.Generator(bit_generator)


class Optimizer(ABC):
    """Black-box maximiser with an ask/tell interface."""

    n_params: int

    @abstractmethod
    def ask(self) -> np.ndarray:
        """Candidates to evaluate next, shape ``(n_candidates, n_params)``."""

    @abstractmethod
    def tell(self, candidates: np.ndarray, rewards: np.ndarray) -> None:
        """Report the rewards of candidates returned by :meth:`ask`."""

    @property
    @abstractmethod
    def best(self) -> tuple[np.ndarray, float]:
        """Best parameters seen so far and their reward."""

    def stop(self) -> bool:
        """True when the optimizer has converged or exhausted its budget."""
        return False

    @abstractmethod
    def state_dict(self) -> dict[str, Any]:
        """Everything needed to resume: JSON-compatible values and numpy arrays."""

    @classmethod
    @abstractmethod
    def from_state(cls, state: dict[str, Any]) -> "Optimizer":
        """Rebuild an optimizer from :meth:`state_dict`."""


class BestAndWorst:
    """Bookkeeping of the batch optimizers (mixin): the best successful episode and the worst reward
    seen, against which failed episodes are penalised (:func:`sanitize_rewards`), with their persistence."""

    _best_params: np.ndarray
    _best_reward: float
    _worst_reward: float | None

    def _init_best(self, params: np.ndarray) -> None:
        """Start with ``params`` as the best guess (reward ``-inf``) and no reward seen."""
        self._best_params = np.array(params, dtype=float)
        self._best_reward = -np.inf
        self._worst_reward = None

    def _record_batch(self, candidates: np.ndarray, rewards: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sanitised rewards and the failed mask of a told batch; updates the worst reward and the best episode."""
        rewards, failed = sanitize_rewards(np.asarray(rewards, dtype=float).ravel(), self._worst_reward)
        if rewards.size != candidates.shape[0]:
            raise ValueError(f"got {rewards.size} rewards for {candidates.shape[0]} candidates")
        low = float(rewards.min())
        self._worst_reward = low if self._worst_reward is None else min(self._worst_reward, low)
        best = int(np.argmax(np.where(failed, -np.inf, rewards)))  # a failed episode is never the best
        if not failed[best] and rewards[best] > self._best_reward:
            self._best_reward = float(rewards[best])
            self._best_params = candidates[best].copy()
        return rewards, failed

    @property
    def best(self) -> tuple[np.ndarray, float]:
        """Best successful parameters told so far and their reward (the initial guess and ``-inf`` before one)."""
        return self._best_params.copy(), self._best_reward

    def _best_state(self) -> dict[str, Any]:
        return {"best_params": self._best_params, "best_reward": float(self._best_reward), "worst_reward": self._worst_reward}

    def _restore_best(self, state: dict[str, Any]) -> None:
        self._best_params = np.asarray(state["best_params"], dtype=float)
        self._best_reward = float(state["best_reward"])
        self._worst_reward = None if state["worst_reward"] is None else float(state["worst_reward"])


class ContextualOptimizer(ABC):
    """Contextual policy search: learns an upper-level policy ``theta = pi(s)``."""

    n_params: int
    n_context: int

    @abstractmethod
    def ask(self, context: np.ndarray) -> np.ndarray:
        """Parameters to try in ``context``, shape ``(n_params,)``."""

    @abstractmethod
    def tell(self, context: np.ndarray, params: np.ndarray, reward: float) -> None:
        """Report the reward of ``params`` in ``context``."""

    @abstractmethod
    def policy(self, context: np.ndarray) -> np.ndarray:
        """Best parameters for ``context`` under the current upper-level policy (no exploration)."""

    def select_context(self, bounds: np.ndarray) -> np.ndarray:
        """Active learning: the context to explore next within ``bounds`` (shape ``(n_context, 2)``).

        Optimizers without active context selection draw uniformly from their own seeded ``rng``.
        """
        rng = getattr(self, "rng", None)
        if not isinstance(rng, np.random.Generator):
            raise AttributeError(
                f"{type(self).__name__} has no seeded `rng` (numpy.random.Generator) to draw contexts from"
            )
        return rng.uniform(bounds[:, 0], bounds[:, 1])

    @abstractmethod
    def state_dict(self) -> dict[str, Any]: ...

    @classmethod
    @abstractmethod
    def from_state(cls, state: dict[str, Any]) -> "ContextualOptimizer": ...


def save_state(state: dict[str, Any], path: str | Path) -> None:
    """Write a state dict as ``path.json`` (scalars, lists, strings) + ``path.npz`` (arrays).

    Writes to temporary files and renames, so a killed run never leaves a half-written state.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, np.ndarray] = {}

    def split(obj: Any, prefix: str) -> Any:
        if isinstance(obj, np.ndarray):
            arrays[prefix] = obj
            return {"__array__": prefix}
        if isinstance(obj, dict):
            return {k: split(v, f"{prefix}.{k}") for k, v in obj.items()}
        if isinstance(obj, (list, tuple)):
            return [split(v, f"{prefix}.{i}") for i, v in enumerate(obj)]
        if isinstance(obj, np.generic):
            return obj.item()
        return obj

    meta = split(state, "state")
    tmp_json = path.with_suffix(".json.tmp")
    tmp_npz = path.with_suffix(".tmp.npz")
    tmp_json.write_text(json.dumps(meta, indent=1))
    np.savez(tmp_npz, **arrays)
    tmp_npz.replace(path.with_suffix(".npz"))
    tmp_json.replace(path.with_suffix(".json"))


def load_state(path: str | Path) -> dict[str, Any]:
    """Inverse of :func:`save_state`."""
    path = Path(path)
    meta = json.loads(path.with_suffix(".json").read_text())
    with np.load(path.with_suffix(".npz"), allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}

    def join(obj: Any) -> Any:
        if isinstance(obj, dict):
            if set(obj) == {"__array__"}:
                return arrays[obj["__array__"]]
            return {k: join(v) for k, v in obj.items()}
        if isinstance(obj, list):
            return [join(v) for v in obj]
        return obj

    return join(meta)
