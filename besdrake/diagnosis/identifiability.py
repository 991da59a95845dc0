"""Structural identifiability: candidate causes that no experiment within the safety gate can tell apart.

Two causes are *structurally* identical when they change every observable in the same way for every plan the
robot may run: a base turned about the vertical and an encoder offset of joint 1 are the same rotation about the
same axis, so either fix gives the same robot. That is a property of the robot and the registry, not of a log,
and it must be reported differently from "these logs cannot tell; this experiment would" (no experiment would).

How it is found: the sensitivities (central finite differences, :data:`STEP_FRACTION` of each parameter's range
either side of nominal) of every observable of the task's trials (:class:`~besdrake.diagnosis.trials.TrialModel`, read
with the full layout: every group, e.g. outcome, object path, joint tracking), each scaled by its typical noise, over
a sample of plans the safety gate allows (:func:`sample_plans`: the task's
:meth:`~besdrake.diagnosis.trials.TrialModel.sample_plans`, which together move every joint). A parameter pair whose columns are collinear over all those plans (the part of one column
not explained by the other below :data:`COLLINEAR_TOL` of its length) is one class; so is a parameter whose column
lies in the span of another effect's parameters (:data:`SPAN_TOL`). Parameters that no observable responds to in
any plan are listed apart (``unobservable``). The result depends only on the registry, the scenario and the plan
sample, so it is computed once and cached as JSON (:func:`structural_classes`).
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from besdrake.diagnosis.trials import TrialModel, default_model, model_for
from besdrake.sim.effects import get_effect

#: Central-difference step, as a fraction of each parameter's realistic range, on either side of nominal.
STEP_FRACTION = 0.02
#: Two parameters are structurally identical when the part of one's scaled sensitivity not explained by the
#: other's is below this fraction of its length over every sampled plan.
COLLINEAR_TOL = 0.02
#: A parameter lies in the span of another effect's parameters below this fraction (same measure).
SPAN_TOL = 0.02
#: A parameter no observable responds to: its scaled sensitivity (per unit of range) is below this.
UNOBSERVABLE_NORM = 1e-6
#: Physical reasons for pairs the data find identical, keyed by the two parameter keys (sorted).
KNOWN_REASONS = {
    ("base_offset.yaw", "joint_offset.joint1"): "the same rotation about the same vertical axis (joint 1 turns about the base's z axis through its origin)",
}
#: Bump when the computation changes (invalidates cached results).
VERSION = 1


@dataclass
class StructuralClass:
    """Parameters (``effect.param`` keys) that change every observable alike for every sampled plan."""

    members: list[str]
    reason: str
    residual: float
    scale: dict[str, float] = field(default_factory=dict)

    def effects(self) -> set[str]:
        return {m.split(".")[0] for m in self.members}

    def statement(self) -> str:
        """The class in words, for a verdict."""
        return (f"{' and '.join(self.members)} are structurally identical ({self.reason}): no experiment within the safety gate "
                "separates them; either fix gives the same robot")


@dataclass
class Identifiability:
    """Structural classes of a registry on a scenario, the parameters nothing observes, and what was sampled."""

    classes: list[StructuralClass]
    unobservable: list[str]
    n_plans: int
    params: list[str]
    key: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {"classes": [asdict(c) for c in self.classes], "unobservable": self.unobservable, "n_plans": self.n_plans,
                "params": self.params, "key": self.key, "version": VERSION}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Identifiability":
        return cls([StructuralClass(**c) for c in d["classes"]], list(d["unobservable"]), int(d["n_plans"]), list(d["params"]), d.get("key", ""))

    def class_of(self, key: str) -> StructuralClass | None:
        return next((c for c in self.classes if key in c.members), None)

    def identical(self, a: Sequence[str], b: Sequence[str]) -> StructuralClass | None:
        """The class that makes the parameter sets ``a`` and ``b`` (keys) the same cause: every parameter of ``a`` not in
        ``b`` is in one class with one of ``b`` not in ``a`` and vice versa; None when they differ structurally."""
        only_a, only_b = set(a) - set(b), set(b) - set(a)
        if not only_a or not only_b:
            return None
        found = None
        for k in only_a | only_b:
            c = self.class_of(k)
            other = only_b if k in only_a else only_a
            if c is None or not (set(c.members) & other):
                return None
            found = found or c
        return found


def sample_plans(limits, model: TrialModel | None = None) -> list:
    """Plans within the robot's ``limits`` (what the safety gate allows) that together move every joint: the task's
    sample (default: the default task's)."""
    return (model or default_model()).sample_plans(limits)


def scaled_sensitivities(executor, effects: Sequence[str], plans: Sequence, model: TrialModel | None = None) -> tuple[list[str], np.ndarray]:
    """Parameter keys and their sensitivities (P, N x F): d feature / d parameter x the parameter's range, each feature
    divided by its group's typical noise (:attr:`~besdrake.diagnosis.trials.Observable.typical`); NaN where a rollout
    failed."""
    from besdrake.diagnosis.fitting import param_specs

    model = model or default_model()
    specs, _ = param_specs(list(effects), model.ordered_params)
    nominal = executor.evaluate(list(plans), [{}] * len(plans))
    layouts = [model.full_layout(model.nominal_layout(o)) for o in nominal]
    scale = np.concatenate([np.full(o.size, o.typical) for o in model.observables])
    keys, cols = [], []
    for s_ in specs:
        h = STEP_FRACTION * (s_.high - s_.low)
        lo, hi = max(s_.low, s_.nominal - h), min(s_.high, s_.nominal + h)
        effs = [{s_.effect: {s_.name: v}} for v in (lo, hi)]
        outs = executor.evaluate([p for p in plans for _ in effs], [e for _ in plans for e in effs])
        f = np.array([[model.simulated_features(outs[2 * i + j], layouts[i]) for j in range(2)] for i in range(len(plans))])
        d = (f[:, 1] - f[:, 0]) / (hi - lo) * (s_.high - s_.low) / scale
        keys.append(s_.key)
        cols.append(d.ravel())
    return keys, np.array(cols)


def classes_from(keys: list[str], J: np.ndarray) -> tuple[list[StructuralClass], list[str]]:
    """Structural classes from scaled sensitivities ``J`` (P, M): collinear pairs of different effects, merged
    transitively, then single parameters in the span of another effect's parameters; and the unobservable keys."""
    A = J[:, np.all(np.isfinite(J), axis=0)]
    norms = np.linalg.norm(A, axis=1)
    unobservable = [k for k, n in zip(keys, norms) if n < UNOBSERVABLE_NORM]
    live = [i for i, n in enumerate(norms) if n >= UNOBSERVABLE_NORM]
    classes = _collinear_classes(keys, A, norms, live)
    in_class = {m for c in classes for m in c.members}
    classes += _span_classes(keys, A, norms, [i for i in live if keys[i] not in in_class], live)
    return classes, unobservable


def _collinear_classes(keys: list[str], A: np.ndarray, norms: np.ndarray, live: list[int]) -> list[StructuralClass]:
    """Pairs of parameters of different effects whose columns are collinear (COLLINEAR_TOL), merged transitively."""
    effect = [k.split(".")[0] for k in keys]
    parent = {i: i for i in live}

    def root(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    worst: dict[tuple[int, int], float] = {}
    for a_i, i in enumerate(live):
        for j in live[a_i + 1:]:
            c = float(A[i] @ A[j]) / (norms[i] * norms[j])
            res = float(np.sqrt(max(0.0, 1.0 - c * c)))
            if effect[i] != effect[j] and res < COLLINEAR_TOL:
                parent[root(j)] = root(i)
                worst[(i, j)] = res
    groups: dict[int, list[int]] = {}
    for i in live:
        groups.setdefault(root(i), []).append(i)
    out = []
    for members in groups.values():
        if len(members) < 2:
            continue
        names = sorted(keys[m] for m in members)
        reason = next((KNOWN_REASONS[p] for p in KNOWN_REASONS if set(p) <= set(names)),
                      "every observable responds to them alike, in proportion, over every sampled plan")
        pairs = {(i, j): r for (i, j), r in worst.items() if i in members}
        scale = {f"{keys[i]}/{keys[j]}": float(A[i] @ A[j]) / float(A[j] @ A[j]) for (i, j) in pairs}
        out.append(StructuralClass(names, reason, max(pairs.values()), scale))
    return out


def _span_classes(keys: list[str], A: np.ndarray, norms: np.ndarray, todo: list[int], live: list[int]) -> list[StructuralClass]:
    """Parameters whose column lies in the span of another effect's (several) parameters (SPAN_TOL)."""
    effect = [k.split(".")[0] for k in keys]
    out = []
    for i in todo:
        for e in dict.fromkeys(effect):
            cols = [j for j in live if effect[j] == e]
            if e == effect[i] or len(cols) < 2:
                continue  # a single column: the pair test
            B = A[cols].T
            coef, *_ = np.linalg.lstsq(B, A[i], rcond=None)
            res = float(np.linalg.norm(A[i] - B @ coef) / norms[i])
            if res < SPAN_TOL:
                used = [keys[j] for j, c in zip(cols, coef) if abs(c) * norms[j] > 1e-3 * norms[i]]
                out.append(StructuralClass([keys[i], *used], f"{keys[i]} acts on every observable as a combination of {', '.join(used)}", res))
    return out


def cache_key(effects: Sequence[str], scenario) -> str:
    """Hash of what the result depends on: the effects' descriptions, the scenario, the method's settings."""
    desc = [get_effect(e).describe() for e in effects]
    blob = json.dumps({"effects": desc, "scenario": scenario.to_dict(), "version": VERSION, "step": STEP_FRACTION,
                       "tol": [COLLINEAR_TOL, SPAN_TOL]}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def cache_dir() -> Path:
    """``$BESDRAKE_CACHE/identifiability`` (default ``~/.cache/besdrake/identifiability``)."""
    base = os.environ.get("BESDRAKE_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "besdrake")
    return Path(base) / "identifiability"


def structural_classes(effects: Sequence[str], scenario="nominal", executor=None, use_cache: bool = True,
                       model: TrialModel | None = None) -> Identifiability:
    """The structural classes of ``effects`` on ``scenario`` (see the module docstring), from the JSON cache when it
    holds them (about 25 parameters x 2 x 10 plans rollouts otherwise; a cache that cannot be written is skipped).
    ``model``: the task's trials (default: the scenario's task's)."""
    from besdrake.sim.executors import make_executor
    from besdrake.sim.scenario import Scenario, load_scenario

    scen = load_scenario(scenario) if not isinstance(scenario, Scenario) else scenario
    key = cache_key(effects, scen)
    path = cache_dir() / f"{key}.json"
    if use_cache and path.is_file():
        try:
            return Identifiability.from_dict(json.loads(path.read_text()))
        except (ValueError, KeyError, TypeError):
            pass  # a damaged cache file is recomputed
    own = executor is None
    ex = executor or make_executor("serial", scenario=scen, limits="flag")
    try:
        model = model or model_for(scen)
        plans = sample_plans(scen.robot.limits, model)
        keys, J = scaled_sensitivities(ex, effects, plans, model)
    finally:
        if own:
            ex.close()
    classes, unobs = classes_from(keys, J)
    result = Identifiability(classes, unobs, len(plans), keys, key)
    if use_cache:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_suffix(f".{os.getpid()}.tmp")  # concurrent diagnoses write their own, then replace
            tmp.write_text(json.dumps(result.to_dict(), indent=1))
            tmp.replace(path)
        except OSError:
            pass
    return result


__all__ = ["structural_classes", "Identifiability", "StructuralClass", "sample_plans", "scaled_sensitivities", "classes_from"]
