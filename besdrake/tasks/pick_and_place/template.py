"""A behaviour template for the grasp: one refined skill generalised over where the box stands on the shelf.

The context is the box's offset ``(dx, dy)`` (m, world axes) from the scene's place on the shelf. For a context the
template

1. carries the base skill (a grasp refined at the scene's place) over to the box's new place
   (:meth:`~besdrake.tasks.pick_and_place.skill_plan.SkillPlanner.carry_over`: the task frame moves with the box, so
   the DMPs' goals keep their offsets from the box and the table place, and the approach starts again from home), and
2. adds a learned correction of the skill's parameters (goals, execution times, close lead:
   :class:`~besdrake.tasks.pick_and_place.parameters.GraspParameterization` without weights), the mean of a Gaussian
   process over the context fitted to the corrections that CMA-ES found at training contexts (zero where the carried
   skill already succeeds).

:func:`learn_grasp_template` refines at the training contexts (each search in its own folder: a killed run resumes)
and fits the template; :func:`evaluate_grasp_template` simulates it at other contexts. The template is saved as JSON
(:meth:`GraspTemplate.to_dict`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from besdrake._io import write_json
from besdrake.tasks.pick_and_place.imitation import GraspSkill
from besdrake.tasks.pick_and_place.parameters import GraspParameterization

#: The GP's prior length scale (m) over the box's offset, and its noise level (in the parameters' units squared).
LENGTH_SCALE = 0.15
NOISE_LEVEL = 1e-4


class GraspTemplate:
    """Skill for a context = carried-over base skill + GP mean of the training corrections (scikit-learn style)."""

    def __init__(self, base_skill: GraspSkill, length_scale: float = LENGTH_SCALE) -> None:
        self.base_skill = base_skill.copy()
        self.length_scale = float(length_scale)
        self.contexts_ = np.zeros((0, 2))
        self.corrections_ = np.zeros((0, 9))
        self._gp = None

    def fit(self, contexts: np.ndarray, corrections: np.ndarray) -> "GraspTemplate":
        """Fit the GP to corrections (n, 9: goals m, times s, close lead s) at contexts (n, 2: dx, dy m)."""
        from sklearn.gaussian_process import GaussianProcessRegressor
        from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

        self.contexts_ = np.atleast_2d(np.asarray(contexts, dtype=float))
        self.corrections_ = np.atleast_2d(np.asarray(corrections, dtype=float))
        if len(self.contexts_) != len(self.corrections_) or self.contexts_.shape[1] != 2:
            raise ValueError("contexts (n, 2) and corrections (n, 9) must have as many rows")
        kernel = ConstantKernel(1.0, "fixed") * RBF(self.length_scale, "fixed") + WhiteKernel(NOISE_LEVEL, "fixed")
        self._gp = GaussianProcessRegressor(kernel, normalize_y=False).fit(self.contexts_, self.corrections_)
        return self

    def correction(self, context) -> np.ndarray:
        """The learned correction (9,) at ``context`` (zero before :meth:`fit` or without training data)."""
        if self._gp is None or not len(self.contexts_):
            return np.zeros(9)
        return np.asarray(self._gp.predict(np.asarray(context, dtype=float).reshape(1, 2))).reshape(9)

    def predict(self, planner, context) -> GraspSkill:
        """The skill for a box at ``context`` (``planner``: the SkillPlanner of that box place)."""
        carried = planner.carry_over(self.base_skill)
        param = GraspParameterization(carried, weights=False)
        return param.from_vector(param.to_vector() + self.correction(context))

    def to_dict(self) -> dict[str, Any]:
        return {"type": "GraspTemplate", "base_skill": self.base_skill.to_dict(), "length_scale": self.length_scale,
                "contexts": self.contexts_.tolist(), "corrections": self.corrections_.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "GraspTemplate":
        t = cls(GraspSkill.from_dict(d["base_skill"]), float(d.get("length_scale", LENGTH_SCALE)))
        return t.fit(d["contexts"], d["corrections"]) if d.get("contexts") else t


@dataclass
class TemplateEvaluation:
    """Template skills simulated at contexts: success and place error per context (m), and their summary."""

    contexts: list[list[float]]
    success: list[bool]
    place_error_m: list[float]
    messages: list[str] = field(default_factory=list)

    @property
    def success_rate(self) -> float:
        return float(np.mean(self.success)) if self.success else 0.0

    def summary(self) -> dict[str, Any]:
        errors = [e for e in self.place_error_m if np.isfinite(e)]
        return {"contexts": len(self.contexts), "success_rate": self.success_rate,
                "median_place_error_m": float(np.median(errors)) if errors else None, **asdict(self)}


def context_grid(region: dict[str, list[float]], n: int, rng: np.random.Generator | None = None) -> np.ndarray:
    """``n`` contexts in ``region`` ({"dx": [lo, hi], "dy": [lo, hi]}, m): its centre and corners first, then
    :func:`random_contexts` (``rng``)."""
    (x0, x1), (y0, y1) = region["dx"], region["dy"]
    fixed = np.array([[0.5 * (x0 + x1), 0.5 * (y0 + y1)], [x0, y0], [x1, y1], [x0, y1], [x1, y0]])
    if n <= len(fixed):
        return fixed[:n]
    return np.vstack([fixed, random_contexts(region, n - len(fixed), rng or np.random.default_rng(0))])


def random_contexts(region: dict[str, list[float]], n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` contexts drawn uniformly from ``region`` with ``rng``: (n, 2)."""
    return np.column_stack([rng.uniform(*region["dx"], n), rng.uniform(*region["dy"], n)])


def learn_grasp_template(base_skill: GraspSkill, scenario: str, contexts: np.ndarray, out_dir: str | Path,
                         settings=None) -> GraspTemplate:
    """Refine the carried-over base skill at each training context (CMA-ES, stopping at the first success; folders
    ``out_dir/context_NN``) and fit a :class:`GraspTemplate` to the corrections; ``template.json`` in ``out_dir``."""
    from besdrake.tasks.pick_and_place.refine import refine_grasp

    from besdrake.sim.scenario import load_scenario
    from besdrake.tasks.pick_and_place.rollout import PickPlaceRollout

    out = Path(out_dir)
    rollout = PickPlaceRollout(load_scenario(scenario))  # the scene's planner facts; built once
    template, rows = GraspTemplate(base_skill), []
    for i, c in enumerate(np.asarray(contexts, dtype=float)):
        carried = _planner(rollout, c).carry_over(template.base_skill)
        res = refine_grasp(carried, scenario, out / f"context_{i:02d}", settings, box_offset=c)
        param = GraspParameterization(carried, weights=False)
        refined = GraspSkill.from_dict(res.best_skill)
        correction = param.to_vector(refined) - param.to_vector() if res.success else np.zeros(param.n_params)
        rows.append({"context": c.tolist(), "success": res.success, "episodes": res.episodes,
                     "initial_success": res.initial_success, "correction": correction.tolist()})
    template.fit([r["context"] for r in rows], [r["correction"] for r in rows])
    write_json(out / "template.json", template.to_dict())
    write_json(out / "training.json", rows)
    return template


def evaluate_grasp_template(template: GraspTemplate, scenario: str, contexts: np.ndarray) -> TemplateEvaluation:
    """Simulate the template's skill at each context (the box moved there in the simulation)."""
    from besdrake.sim.scenario import load_scenario
    from besdrake.tasks.pick_and_place.rollout import PickPlaceRollout

    rollout = PickPlaceRollout(load_scenario(scenario))
    ev = TemplateEvaluation([], [], [], [])
    for c in np.asarray(contexts, dtype=float):
        planner = _planner(rollout, c)
        plan = planner.plan(template.predict(planner, c)).plan
        out = rollout.rollout(plan, box_offset=np.array([c[0], c[1], 0.0]))
        ev.contexts.append(c.tolist())
        ev.success.append(bool(out.success))
        ev.place_error_m.append(float(out.place_error))
        ev.messages.append(out.message)
    return ev


def _planner(rollout, context):
    """The SkillPlanner of a PickPlaceRollout's scene with the box at ``context``."""
    from besdrake.tasks.pick_and_place.skill_plan import SkillPlanner

    return SkillPlanner.for_rollout(rollout, box_offset=np.asarray(context, dtype=float))
