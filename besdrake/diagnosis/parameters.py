"""Parameter parsimony: the named cause keeps only the parameters the log needs.

The parameters of a large effect (six encoder offsets, a base pose) are chosen on the linear model at nominal
(:func:`~besdrake.diagnosis.fitting.linear_fit` with ``select``), where every residual entry counts as independent. One
trial's unmodelled perturbation moves many of its entries together, so a few more parameters than the effect needs
are chosen and then absorb that scatter (issue 25's diagnosis benchmark, seed 0, trial 72: a base yaw of -0.057 rad was fitted
as joint-1, 4, 5 and 6 offsets of -0.075, -0.022, 0.002 and 0.081 rad; a joint-1 offset alone predicts the same
outcomes to 0.23 noise SD). A user who trusts such an answer recalibrates joints that are fine.

:func:`prune_parameters` applies to parameters the rule :func:`~besdrake.diagnosis.selection.parsimony` applies to
whole effects: a parameter is reset to nominal when the cause without it is still adequate (lack-of-fit test) and its
predictions stay within :data:`~besdrake.diagnosis.settings.MATERIAL` noise SD of the full fit's (median over the trials,
every measured group), backward, one parameter at a time, the smallest loss of fit first; every effect keeps one. The
diagnosis judges its verdict and confidence on the cause as selected and names the pruned one
(:func:`besdrake.diagnosis.core._name_needed_parameters`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from besdrake.diagnosis import fitting, noise
from besdrake.diagnosis.settings import ALPHA, MATERIAL
from besdrake.diagnosis.stats import _lack_of_fit_p, _material_change

#: Per round, how many of the parameters whose reset costs the least fit (predicted on the fit's Jacobian) are simulated,
#: refined and judged; the others stay.
PRUNE_TRIES = 2


def _without(prob: fitting.Problem, fit: fitting.CandidateFit, j: int) -> tuple[float, list[fitting.ParamSpec], np.ndarray, np.ndarray]:
    """``fit`` with parameter ``j`` at nominal and the others moved by one Gauss-Newton step on ``fit``'s Jacobian to
    make up for it (no rollouts): the chi2 that linear model predicts, the specs, theta and weighted Jacobian."""
    keep = [i for i in range(len(fit.specs)) if i != j]
    specs = [fit.specs[i] for i in keep]
    A = fit.jac[:, keep]
    r = prob.weighted(fit.y_fit) - fit.jac[:, j] * (fit.specs[j].nominal - fit.theta[j])
    lo, hi = np.array([s.low for s in specs]), np.array([s.high for s in specs])
    theta = np.clip(fit.theta[keep] + fitting._solve_step(A, r, specs, fit.theta[keep]), lo, hi)
    r_pred = r - A @ (theta - fit.theta[keep])
    return float(r_pred @ r_pred), specs, theta, A


def _droppable(fit: fitting.CandidateFit, n_params: dict[str, int]) -> list[int]:
    """Indices of ``fit``'s parameters that may go: of effects fitted by selection (more than DENSE_PARAMS
    parameters), never an effect's last one."""
    count: dict[str, int] = {}
    for s in fit.specs:
        count[s.effect] = count.get(s.effect, 0) + 1
    return [j for j, s in enumerate(fit.specs) if n_params.get(s.effect, 0) > fitting.DENSE_PARAMS and count[s.effect] > 1]


def prune_parameters(prob: fitting.Problem, fit: fitting.CandidateFit, simulate_one: Callable[[dict], np.ndarray], nm: noise.NoiseModel,
                     groups: list[str], n_params: dict[str, int], iterations: int) -> tuple[fitting.CandidateFit, list[str]]:
    """``fit`` (refined, with its Jacobian) less the parameters the log does not need (module docstring), refined
    again after each one dropped, and the parameters dropped (``effect.parameter``). ``n_params``: how many
    parameters each effect has; ``fit`` itself is returned when none may go."""
    if fit.y_fit is None or fit.jac is None or fit.jac.shape[1] != len(fit.specs):
        return fit, []
    current, dropped = fit, []
    while True:
        options = sorted(((*_without(prob, current, j), j) for j in _droppable(current, n_params)), key=lambda o: o[0])
        chosen = None
        for _c2, specs, theta, A, j in options[:PRUNE_TRIES]:
            y = simulate_one(fitting.effects_from(specs, theta))
            r = prob.weighted(y)
            cand = replace(current, specs=specs, theta=theta, jac=A, y_fit=y, chi2=float(r @ r), k=len(specs), stderr=fitting.stderr_from(A, specs),
                           inactive=current.inactive + [current.specs[j].key], fresh_jacobian=False)
            fitting.refine(prob, cand, simulate_one, iterations=iterations, starts=[(theta, y)], try_linear=False, nominal_secants=False)
            if _immaterial(prob, fit, cand, nm, groups):
                chosen = (j, cand)
                break
        if chosen is None:
            return current, dropped
        dropped.append(current.specs[chosen[0]].key)
        current = chosen[1]


def _immaterial(prob: fitting.Problem, full: fitting.CandidateFit, sub: fitting.CandidateFit, nm: noise.NoiseModel, groups: list[str]) -> bool:
    """Whether ``sub`` is adequate and predicts every measured group within MATERIAL noise SD of ``full``."""
    if _lack_of_fit_p(prob, sub.y_fit, sub.k, nm, groups)[0] < ALPHA:
        return False
    return all(v < MATERIAL for v in _material_change(full.y_fit, sub.y_fit, nm, groups).values())
