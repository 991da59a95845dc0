"""Result types of a diagnosis: group comparisons, ranked causes, allowed effects, the held-out gain, the Diagnosis."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

from besdrake.diagnosis.noise import NoiseModel
from besdrake.sim.scenario import Scenario


class DiagnosisError(ValueError):
    """The log cannot be diagnosed (too few usable trials, unknown candidate effect, ...)."""


# ---------------------------------------------------------------------------------------------- results
@dataclass
class GroupComparison:
    """Sim-vs-lab residuals of one feature group over all trials: mean, its standard error, systematic?"""

    group: str
    unit: str
    n_trials: int
    mean: list[float]
    stderr: list[float]
    rms: float
    noise_sd: float
    systematic: bool
    chi2: float
    dof: int


@dataclass
class Cause:
    """A ranked candidate: effects, fitted parameters with standard errors, BIC and its delta to the best."""

    effects: tuple[str, ...]
    parameters: list[dict]
    bic: float
    delta_bic: float
    chi2: float
    n: int
    k: int
    refined: bool
    p_value: float
    unobservable: list[str] = field(default_factory=list)
    p_groups: dict[str, float] = field(default_factory=dict)
    k_eff: float = 0.0
    left_nominal: list[str] = field(default_factory=list)
    selection_penalty: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        return {
            "effect": " + ".join(self.effects) if self.effects else "none",
            "effects": list(self.effects),
            "parameters": {p["effect"] + "." + p["parameter"]: {k: p[k] for k in ("value", "stderr", "unit", "at_bound", "constrained", "stderr_source")} for p in self.parameters},
            "bic": self.bic,
            "delta_bic": self.delta_bic,
            "chi2": self.chi2,
            "n": self.n,
            "k": self.k,
            "k_effective": self.k_eff,
            "refined_with_rollouts": self.refined,
            "p_value": self.p_value,
            "p_value_by_group": self.p_groups,
            "unobservable": self.unobservable,
            "left_nominal": self.left_nominal,
            "selection_penalty": self.selection_penalty,
        }


@dataclass
class AllowedEffect:
    """What a log without a detectable discrepancy still allows of one candidate effect.

    ``allowed``: per parameter the interval (in its unit) not ruled out at level :data:`ALPHA` when that parameter
    alone deviates (likelihood ratio on the linearised model, each end the data set checked with rollouts and widened
    where the trials respond less than linearly, :func:`_verify_interval_ends`; clipped to the realistic bounds); ``max_fraction``: the largest allowed deviation from
    nominal as a fraction of the parameter's realistic range; ``excluded``: every deviation of at least
    :data:`EXCLUDE_FRACTION` of the range is ruled out; ``unconstrained``: the log allows every parameter (nearly, :data:`UNCONSTRAINED_COVER`)
    anywhere in its realistic range (the logged signals say nothing about this effect; otherwise they bound at least one of its
    parameters and a larger deviation would have been seen); ``trials_needed``: about how many trials like the logged ones
    would exclude it (None: the logged signals do not respond to it at all); ``recommendation``: the recording or
    experiment that would show it; ``beside``: per parameter, the wider intervals the log allows it where one other
    parameter (key ``effect.parameter``) moves with it to compensate (:func:`~besdrake.diagnosis.allowed._hiding_pairs`:
    two deviations that hide each other), only those at least :data:`~besdrake.diagnosis.settings.HIDE_WIDENING` times as wide.
    """

    effect: str
    allowed: dict[str, tuple[float, float]]
    nominal: dict[str, float]
    units: dict[str, str]
    max_fraction: float
    excluded: bool
    trials_needed: int | None
    recommendation: str
    unconstrained: bool = False
    beside: dict[str, dict[str, tuple[float, float]]] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"effect": self.effect, "allowed": {k: [float(a), float(b)] for k, (a, b) in self.allowed.items()}, "nominal": dict(self.nominal),
                "units": dict(self.units), "max_allowed_fraction_of_range": self.max_fraction, "excluded": self.excluded,
                "unconstrained": self.unconstrained, "trials_needed": self.trials_needed, "recommendation": self.recommendation,
                "beside": {k: {o: [float(a), float(b)] for o, (a, b) in v.items()} for k, v in self.beside.items()}}

    def hiding_pairs(self) -> list[tuple[float, str, str, tuple[float, float]]]:
        """``(widening, parameter, other, (lo, hi))`` per entry of :attr:`beside`: how many times wider the interval the
        log allows ``parameter`` beside ``other`` is than alone."""
        out = []
        for name, partners in self.beside.items():
            lo0, hi0 = self.allowed[name]
            out += [((hi - lo) / max(hi0 - lo0, 1e-12), name, other, (lo, hi)) for other, (lo, hi) in partners.items()]
        return out

    def describe(self) -> str:
        """``effect (p in [lo, hi] unit, ...)`` for the allowed parameters that reach the exclusion threshold."""
        parts = []
        for k, (a, b) in self.allowed.items():
            parts.append(f"{k} {a:.3g}..{b:.3g} {self.units.get(k, '')}".rstrip())
        return f"{self.effect} ({'; '.join(parts)})"


@dataclass
class Gain:
    """Held-out outcome disparity (e.g. of the touchdowns, m) before/after refinement: medians with bootstrap 95% CIs."""

    median_disparity_before_m: float
    median_disparity_after_m: float
    ci_before_m: tuple[float, float]
    ci_after_m: tuple[float, float]
    ratio_after_before: float
    n_heldout: int
    folds: int
    disparity_before: list[float] = field(default_factory=list)
    disparity_after: list[float] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        d = {k: v for k, v in vars(self).items() if k not in ("disparity_before", "disparity_after")}
        d["ci_before_m"], d["ci_after_m"] = list(self.ci_before_m), list(self.ci_after_m)
        return d


@dataclass
class Diagnosis:
    """Everything :func:`diagnose` found (JSON via :meth:`summary`).

    ``explained``: the chosen model (the best cause, or the nominal simulation when no candidate improves on it
    significantly) passes the lack-of-fit test against the measured noise. When the chosen model is the nominal one,
    that means only "no discrepancy beyond the noise": ``cannot_tell`` then lists the candidate effects the log
    cannot exclude (with the magnitudes it still allows and what would show them) and ``excluded`` those it rules
    out; ``confidence`` is "high" only if every candidate is excluded. Both lists are empty when a cause was named.
    A named cause has ``confidence`` "high" when it passes the lack-of-fit test at :data:`CONFIDENT_P`, no rival fits
    about as well, and the log records more than the trials' outcome (on outcomes alone an unknown effect can pass).
    ``indistinguishable``: the rivals the log cannot tell from the named cause, each with what would separate them; on
    outcome-only logs also the pairs "cause + X" for a second effect X the log cannot exclude beside a single cause
    (``addition``: True, :mod:`~besdrake.diagnosis.additions`) and near aliases of it (``alias``: True).
    """

    explained: bool
    confidence: str
    verdict: str
    causes: list[Cause]
    best: Cause | None
    indistinguishable: list[dict]
    noise: NoiseModel
    comparison: list[GroupComparison]
    gain: Gain | None
    groups_measured: list[str]
    n_trials: int
    n_used: int
    skipped: list[dict]
    per_trial: list[dict]
    scenario: Scenario
    timings: dict[str, float]
    n_rollouts: int
    notes: list[str] = field(default_factory=list)
    refined_scenario_path: str | None = None
    cannot_tell: list[AllowedEffect] = field(default_factory=list)
    excluded: list[AllowedEffect] = field(default_factory=list)
    #: Classes of candidate parameters no experiment within the safety gate separates (members, reason;
    #: :mod:`~besdrake.diagnosis.identifiability`), whatever the log: reported apart from "these logs cannot tell".
    structural: list[dict] = field(default_factory=list)
    #: When not explained: where the residual lives and a data-driven residual model with its held-out gain
    #: (:class:`~besdrake.diagnosis.residual.ResidualReport` as a dict), else None.
    residual: dict | None = None
    #: What the confidence of a named cause rests on (:func:`~besdrake.diagnosis.verdict.confidence_basis`; empty when
    #: no cause was named).
    confidence_basis: dict = field(default_factory=dict)

    def refined_effects(self) -> dict[str, dict[str, float]]:
        if not self.best or not self.best.effects:
            return {}
        out: dict[str, dict[str, float]] = {}
        for p in self.best.parameters:
            out.setdefault(p["effect"], {})[p["parameter"]] = round(float(p["value"]), 6)
        return out

    def refined_scenario(self) -> dict[str, Any]:
        """The base scenario as a YAML-ready dict with the fitted effects under ``effects``."""
        d = self.scenario.to_dict()
        eff = {k: dict(v) for k, v in d.get("effects", {}).items()}
        for name, vals in self.refined_effects().items():
            eff.setdefault(name, {}).update(vals)
        d["effects"] = eff
        d["name"] = f"{self.scenario.name}_refined"
        what = self.best.to_dict()["effect"] if self.best else "none"
        d["description"] = f"{self.scenario.name} refined by besdrake diagnose: fitted {what} ({'explained' if self.explained else 'NOT explained'}); {self.verdict}"
        return d

    def summary(self) -> dict[str, Any]:
        return {
            "explained": self.explained,
            "confidence": self.confidence,
            "verdict": self.verdict,
            "causes": [c.to_dict() for c in self.causes],
            "best": self.best.to_dict() if self.best else None,
            "indistinguishable": self.indistinguishable,
            "cannot_tell": [a.to_dict() for a in self.cannot_tell],
            "excluded": [a.to_dict() for a in self.excluded],
            "structurally_identical": self.structural,
            "residual": self.residual,
            "confidence_basis": self.confidence_basis,
            "gain": self.gain.to_dict() if self.gain else None,
            "noise": self.noise.to_dict(),
            "comparison": [vars(g) for g in self.comparison],
            "groups_measured": self.groups_measured,
            "n_trials": self.n_trials,
            "n_used": self.n_used,
            "skipped": self.skipped,
            "refined_scenario": self.refined_scenario_path,
            "refined_effects": self.refined_effects(),
            "timings_s": self.timings,
            "n_rollouts": self.n_rollouts,
            "notes": self.notes,
        }

    def to_json(self) -> str:
        return json.dumps(self.summary(), indent=2, default=float)
