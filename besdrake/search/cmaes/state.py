"""Saving and restoring a ``cma.CMAEvolutionStrategy`` without pickle: the attributes that change during ``tell()``
and determine the next candidates and the termination tests, read and written by their dotted paths."""

from __future__ import annotations

from typing import Any

import cma
import numpy as np

# Attributes of cma.CMAEvolutionStrategy (and its sub-objects) that change during tell() and
# determine the next candidates and the termination tests. Paths are relative to the strategy.
# "C", "B", "D", "dC", "pc2": the diagonal covariance of separable CMA-ES (cma option CMA_diagonal) lives on the strategy itself
_ARRAY_ATTRS = ("mean", "mean_old", "mean_after_tell", "pc", "pc_neg", "sm.C", "sm.B", "sm.D", "adapt_sigma.ps", "sigma_vec.scaling",
                "C", "B", "D", "dC", "pc2", "best.x", "best.x_geno")  # best.*: what elitist CMA-ES (CMA_elitist) re-injects
_SCALAR_ATTRS = (
    "sigma",
    "_sigma_old",
    "countiter",
    "countevals",
    "sm.count_tell",
    "sm.last_update",
    "sm.count_eigen",
    "sm._corr_condition",
    "sm._corr_condition_count_eigen",
    "adapt_sigma.delta",
    "adapt_sigma._last_multiplier",
    "adapt_sigma._ps_updated_iteration",
    "adapt_sigma.is_initialized",
    "fit.median",
    "fit.median0",
    "fit.median_min",
    "fit.median_previous",
    "fit.median_got_worse",
    "fit.flatfit_iterations",
    "sigma_vec.is_identity",
    "best.f",
    "best.evals",
)
_LIST_ATTRS = ("fit.hist", "fit.histbest", "fit.histmedian", "fit.fit", "hsiglist")


def _get(obj: Any, path: str) -> Any:
    for name in path.split("."):
        obj = getattr(obj, name)
    return obj


def _set(obj: Any, path: str, value: Any) -> None:
    *parents, name = path.split(".")
    for parent in parents:
        obj = getattr(obj, parent)
    setattr(obj, name, value)


def _has(obj: Any, path: str) -> bool:
    try:
        _get(obj, path)
    except AttributeError:
        return False
    return True


def es_state(es: cma.CMAEvolutionStrategy) -> dict[str, Any]:
    """The strategy's changing attributes: ``es_arrays``, ``es_scalars`` and ``es_lists`` by path."""
    arrays = {path: np.array(_get(es, path), dtype=float) for path in _ARRAY_ATTRS if _has(es, path) and _get(es, path) is not None}
    scalars = {}
    for path in _SCALAR_ATTRS:
        if _has(es, path):
            value = _get(es, path)
            scalars[path] = value.item() if isinstance(value, np.generic) else value
    lists = {path: np.array(_get(es, path), dtype=float) for path in _LIST_ATTRS if _has(es, path)}
    return {"es_arrays": arrays, "es_scalars": scalars, "es_lists": lists}


def restore_es(es: cma.CMAEvolutionStrategy, state: dict[str, Any]) -> None:
    """Write what :func:`es_state` saved back into a fresh strategy of the same settings."""
    for path, value in state["es_arrays"].items():
        _set(es, path, np.array(value, dtype=float))
    for path, value in state["es_scalars"].items():
        _set(es, path, value)
    for path, value in state["es_lists"].items():
        _set(es, path, [float(v) for v in np.asarray(value).ravel()])
    if _has(es, "sm._inverse_root_C"):
        es.sm._inverse_root_C = None  # recomputed lazily from the restored B, D
    if es.countiter > 0:  # cma creates its wall-clock timer in the first ask()
        es.timer = cma.utilities.utils.ElapsedWCTime()
        es.timer.pause()
        es._stoptolxstagnation.update(es.mean)
