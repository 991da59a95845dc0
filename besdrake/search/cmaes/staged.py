"""CMA-ES first in a low-dimensional affine subspace of meta-parameters, then in the full space."""

from __future__ import annotations

from typing import Any

import numpy as np

from besdrake.search.base import BestAndWorst, Optimizer, rng_from_state
from besdrake.search.cmaes.core import CMAES


class StagedCMAES(BestAndWorst, Optimizer):
    """CMA-ES first in a low-dimensional affine subspace, then in the full space (a maximiser).

    Stage 1 searches ``z`` (``k`` dimensions) with candidates ``x = clip(x0 + basis @ z, bounds)``: a few
    meta-parameters with a large effect (e.g. joint offsets, goals, execution time of a DMP) move the
    search far from ``x0`` in few episodes. After ``subspace_evaluations`` episodes (or when that CMA-ES
    stops) stage 2 runs CMA-ES on all ``n`` parameters from the best candidate of stage 1 with step size
    ``sigma_full``. ``ask`` always returns full-space candidates, so the episode log and the rewards are
    those of the full problem. One Generator drives both stages; the state (both stages, the stage
    counter) is saved and restored like :class:`CMAES` (a resumed run asks the same candidates).
    """

    def __init__(
        self,
        x0: np.ndarray,
        basis: np.ndarray,
        sigma_subspace: float,
        sigma_full: float,
        rng: np.random.Generator,
        *,
        subspace_evaluations: int,
        popsize_subspace: int | None = None,
        popsize: int | None = None,
        bounds: np.ndarray | None = None,
        cma_options: dict[str, Any] | None = None,
    ) -> None:
        x0 = np.asarray(x0, dtype=float).ravel()
        basis = np.asarray(basis, dtype=float)
        if x0.size == 0 or not np.isfinite(x0).all():
            raise ValueError(f"x0 must be a non-empty finite vector, got {x0!r}")
        if basis.ndim != 2 or basis.shape[0] != x0.size or basis.shape[1] < 1 or not np.isfinite(basis).all():
            raise ValueError(f"basis must be a finite ({x0.size}, k >= 1) array, got shape {basis.shape}")
        for name, v in (("sigma_subspace", sigma_subspace), ("sigma_full", sigma_full)):
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive finite step size, got {v!r}")
        if subspace_evaluations < 0:
            raise ValueError(f"subspace_evaluations must be >= 0, got {subspace_evaluations}")
        self.n_params = x0.size
        self.x0 = x0
        self.basis = basis
        self.bounds = None if bounds is None else CMAES._check_bounds(bounds, x0)
        self.sigma_subspace = float(sigma_subspace)
        self.sigma_full = float(sigma_full)
        self.subspace_evaluations = int(subspace_evaluations)
        self.popsize_subspace = popsize_subspace
        self.popsize = popsize
        self.cma_options = dict(cma_options or {})
        self.rng = rng
        self.stage = 1
        self.n_subspace_told = 0
        self._init_best(x0)
        self.subspace: CMAES | None = CMAES(np.zeros(basis.shape[1]), sigma_subspace, rng, popsize=popsize_subspace, cma_options=self.cma_options)
        self.full: CMAES | None = None
        if self.subspace_evaluations == 0:
            self._switch()

    def _embed(self, Z: np.ndarray) -> np.ndarray:
        X = self.x0 + np.atleast_2d(Z) @ self.basis.T
        return X if self.bounds is None else np.clip(X, self.bounds[:, 0], self.bounds[:, 1])

    def _switch(self) -> None:
        """Start stage 2 at the best candidate so far (kept strictly inside the bounds)."""
        x = self._best_params.copy()
        if self.bounds is not None:
            x = np.clip(x, self.bounds[:, 0] + 1e-9, self.bounds[:, 1] - 1e-9)
        rng = self.subspace.rng if self.subspace is not None else self.rng
        self.full = CMAES(x, self.sigma_full, rng, popsize=self.popsize, bounds=self.bounds, cma_options=self.cma_options)
        self.stage = 2
        self.subspace = None

    def ask(self) -> np.ndarray:
        if self.stage == 1:
            return self._embed(self.subspace.ask())
        return self.full.ask()

    def tell(self, candidates: np.ndarray, rewards: np.ndarray) -> None:
        candidates = np.asarray(candidates, dtype=float)
        rewards = np.asarray(rewards, dtype=float).ravel()
        if self.stage == 1:
            Z = self.subspace.ask()  # the pending batch (ask is idempotent until tell)
            if candidates.shape != (Z.shape[0], self.n_params) or not np.allclose(candidates, self._embed(Z)):
                raise ValueError("tell() needs the candidates returned by the last ask()")
            self._record_batch(candidates, rewards)
            self.subspace.tell(Z, rewards)
            self.n_subspace_told += rewards.size
            if self.n_subspace_told >= self.subspace_evaluations or self.subspace.stop():
                self._switch()
            return
        self._record_batch(candidates, rewards)
        self.full.tell(candidates, rewards)

    @property
    def mean(self) -> np.ndarray:
        """Mean of the current search distribution, in the full space."""
        return self._embed(self.subspace.mean)[0] if self.stage == 1 else self.full.mean

    def stop(self) -> bool:
        return self.stage == 2 and self.full.stop()

    def state_dict(self) -> dict[str, Any]:
        return {
            "type": "StagedCMAES",
            "config": {
                "x0": self.x0,
                "basis": self.basis,
                "sigma_subspace": self.sigma_subspace,
                "sigma_full": self.sigma_full,
                "subspace_evaluations": self.subspace_evaluations,
                "popsize_subspace": self.popsize_subspace,
                "popsize": self.popsize,
                "bounds": self.bounds,
                "cma_options": self.cma_options,
            },
            "stage": self.stage,
            "n_subspace_told": self.n_subspace_told,
            **self._best_state(),
            "subspace": None if self.subspace is None else self.subspace.state_dict(),
            "full": None if self.full is None else self.full.state_dict(),
        }

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "StagedCMAES":
        if state.get("type") != "StagedCMAES":
            raise ValueError(f"not a StagedCMAES state (type={state.get('type')!r})")
        cfg = state["config"]
        inner = state["subspace"] if state["subspace"] is not None else state["full"]
        opt = cls(
            np.asarray(cfg["x0"]),
            np.asarray(cfg["basis"]),
            cfg["sigma_subspace"],
            cfg["sigma_full"],
            rng_from_state(inner["rng"]),
            subspace_evaluations=max(1, int(cfg["subspace_evaluations"])),
            popsize_subspace=cfg["popsize_subspace"],
            popsize=cfg["popsize"],
            bounds=None if cfg["bounds"] is None else np.asarray(cfg["bounds"]),
            cma_options=cfg["cma_options"],
        )
        opt.subspace_evaluations = int(cfg["subspace_evaluations"])
        opt.stage = int(state["stage"])
        opt.n_subspace_told = int(state["n_subspace_told"])
        opt._restore_best(state)
        if opt.stage == 1:
            opt.subspace = CMAES.from_state(state["subspace"])
            opt.rng = opt.subspace.rng
        else:
            opt.subspace = None
            opt.full = CMAES.from_state(state["full"])
            opt.rng = opt.full.rng
        return opt
