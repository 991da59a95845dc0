"""What a task tells the diagnosis about its trials: the observables of a trial and how to read them.

The diagnosis engine is generic over *trials*: a logged motion plan and its measurement on one side, the rollout
of the same plan in simulation on the other, both read into the same feature vector (groups of observables, e.g.
an outcome, a tracked object's path, joint tracking errors). A task plugs its own in through
:meth:`besdrake.task.Task.diagnosis_model`, a :class:`TrialModel`: the observable groups with their units and noise
scales, how a measured trial and a simulated outcome are read at the same times (a *layout* per trial, built once
from the measurement and the nominal rollout), the signal noise a log itself shows, the designed diagnosis
experiments, the lab's trial-to-trial scatter of where an object is placed (:class:`PlacementScatter`), and the
words the report uses (e.g. "pick", "touchdown").
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np


@dataclass(frozen=True)
class Observable:
    """One group of features of a trial.

    ``floor``: the smallest SD a simulation can be trusted to reproduce; ``typical``: the noise of the group when the
    log does not hold it (to judge what *would* separate causes); ``record``: what to record to get it (advice);
    ``axis_classes``: feature indices within the group that share a base SD in the noise model (e.g. the horizontal
    and the vertical part of a path); ``material_factor``: a prediction change counts as material at this many noise
    SDs times the engine's threshold (the outcome group always counts, at 1)."""

    name: str
    size: int
    unit: str
    floor: float
    typical: float
    record: str
    axis_classes: tuple[tuple[int, ...], ...] = ()
    material_factor: float = 1.0


@dataclass
class SignalNoise:
    """Noise SDs the log's own signals show (e.g. marker noise propagated through a path fit), per group.

    ``bounds``: groups whose figure is also a lower bound of the noise measured from repeated plans; ``notes``:
    lines for the diagnosis' notes."""

    sd: dict[str, float] = field(default_factory=dict)
    source: dict[str, str] = field(default_factory=dict)
    bounds: set[str] = field(default_factory=set)
    notes: list[str] = field(default_factory=list)


class PlacementScatter(ABC):
    """The lab's trial-to-trial scatter of where an object is placed at the start (2-D, m per axis), which the
    trial's outcome depends on nonlinearly: every simulated trial is compared as its mean over that scatter.

    ``effect``: the registry effect that sets the placement (its parameters a habit ``{x, y}``); ``what``: the
    scatter in words, ``short``: the placement as a noun, ``range_what``: what bounds it; ``max_sd``/``default_sd``: the accepted and the default scatter (m); ``starts``: placement
    habits at which the placement effect is also tried before its refinement (the expected trial is kinked in it)."""

    effect: str = ""
    what: str = ""
    short: str = ""
    range_what: str = ""
    max_sd: float = 0.0
    default_sd: float = 0.0
    starts: tuple[dict[str, float], ...] = ()

    def points(self, sd: float) -> np.ndarray:
        """The four placements (m, x/y) whose mean stands for the N(0, sd^2)-per-axis scatter: (+-a, +-a) with
        a = sd sqrt(2/pi). Exact for the mean of anything linear or linear in |x| and |y|, symmetric (the linear part
        cancels); pure quadratic terms come out at 2/pi of their value. Deterministic, so that every candidate sees
        the same points (a smooth fit)."""
        a = sd * np.sqrt(2.0 / np.pi)
        return np.array([[a, a], [a, -a], [-a, a], [-a, -a]])

    @abstractmethod
    def quadrature(self, sd: float) -> tuple[np.ndarray, np.ndarray]:
        """Points (K, 2; the centre first) and weights of a rule for the variance over the scatter."""

    @abstractmethod
    def placed(self, habit: dict[str, float], d: np.ndarray) -> dict[str, float]:
        """The placement effect's parameters of ``habit`` moved by ``d`` (m, x/y), within its bounds."""


class TrialModel(ABC):
    """A task's trials as the diagnosis sees them (see the module docstring). Subclasses set the class attributes
    and implement the abstract methods; the engine never looks inside a layout, a measurement or an outcome."""

    #: The task's word for one trial (e.g. "pick"; the report adds an "s" for the plural).
    noun: str = "trial"
    #: The observable groups, in the order of a feature vector (the outcome group among them).
    observables: tuple[Observable, ...] = ()
    #: The group that is the trial's outcome: the gain is measured on it and it is always compared.
    outcome: str = ""
    #: Outcome noise SD (per axis) assumed when the log repeats no plan, where it comes from, and the note.
    prior_outcome_sd: float = 0.0
    prior_outcome_source: str = ""
    prior_outcome_note: str = ""
    #: Parameters bounded above by another parameter of the same effect: {(effect, param): other} (fitted stepping
    #: down; the other follows it up when a fit would cross them).
    ordered_params: dict[tuple[str, str], str] = {}
    #: The lab's placement scatter (None: trials do not depend on one).
    scatter: PlacementScatter | None = None
    #: How the per-trial table's extra columns (:meth:`details_columns`) were obtained.
    details_note: str = ""

    # --- the feature vector -----------------------------------------------------------------------------------
    def slices(self) -> dict[str, slice]:
        out, i = {}, 0
        for o in self.observables:
            out[o.name] = slice(i, i + o.size)
            i += o.size
        return out

    def names(self) -> list[str]:
        return [o.name for o in self.observables]

    @property
    def n_features(self) -> int:
        return sum(o.size for o in self.observables)

    def group(self, name: str) -> Observable:
        return next(o for o in self.observables if o.name == name)

    def units(self) -> dict[str, str]:
        return {o.name: o.unit for o in self.observables}

    def typical(self) -> dict[str, float]:
        return {o.name: o.typical for o in self.observables}

    def plural(self) -> str:
        return self.noun + "s"

    # --- reading trials ---------------------------------------------------------------------------------------
    @abstractmethod
    def usable(self, measurement) -> tuple[bool, str]:
        """Whether a measured trial can be compared with the simulation, and why not."""

    @abstractmethod
    def make_layout(self, measurement, nominal) -> Any:
        """Where to read the features of one trial, from its measurement and its plan's nominal rollout outcome."""

    @abstractmethod
    def nominal_layout(self, nominal) -> Any:
        """A layout from the nominal outcome alone (no measurement), before :meth:`full_layout`."""

    @abstractmethod
    def full_layout(self, layout) -> Any:
        """A layout with every group filled in (for predictions of unmeasured signals)."""

    @abstractmethod
    def measured_features(self, measurement, layout) -> tuple[np.ndarray, float | None]:
        """Feature vector of a measured trial (NaN where not measured) and a fit residual for the noise (or None)."""

    @abstractmethod
    def simulated_features(self, outcome, layout) -> np.ndarray:
        """Feature vector of a simulated outcome read at ``layout`` (NaN where the rollout failed)."""

    def signal_noise(self, used: Sequence, layouts: Sequence, fit_residuals: Sequence) -> SignalNoise:
        """What the log's signals show of their own noise (default: nothing)."""
        return SignalNoise()

    def trial_details(self, features: np.ndarray, layout, plan) -> dict[str, float]:
        """Derived figures of one trial for the per-trial table (e.g. a release speed), from a feature vector."""
        return {}

    def details_columns(self) -> list[tuple[str, str, float, str]]:
        """The per-trial table's extra columns: (header, detail key without its ``_lab``/``_nominal`` suffix, scale,
        format)."""
        return []

    def behaviour_features(self, plans: Sequence, nominal_features: np.ndarray) -> tuple[list[str], np.ndarray]:
        """Per trial, features of the behaviour a residual may follow (names, (N, k)); default: the nominal outcome."""
        s = self.slices()[self.outcome]
        return [f"{self.outcome}_{i}" for i in range(s.stop - s.start)], nominal_features[:, s]

    # --- experiments ------------------------------------------------------------------------------------------
    def design_experiments(self, n: int, repeats: int, seed: int = 0, limits=None, **options) -> list:
        """``n`` plans for a diagnosis log, ``repeats`` of them repeated (the task's designed experiment)."""
        raise NotImplementedError(f"no designed diagnosis experiment for {self.plural()}")

    def sample_plans(self, limits) -> list:
        """Plans within ``limits`` that together move every joint (for structural identifiability)."""
        raise NotImplementedError(f"no plan sample for {self.plural()}")

    # --- words ------------------------------------------------------------------------------------------------
    def spread_advice(self) -> str:
        """What to run when the candidates predict the same signals for every logged trial."""
        return (f"{self.plural()} that spread the plans more widely and repeat each several times: the fitted candidates "
                f"predict nearly the same signals for the logged {self.plural()}")

    def wider_plans_hint(self) -> str:
        """What makes fewer trials enough to exclude an effect."""
        return "plans that spread more widely need fewer"

    def other_plans_hint(self) -> str:
        """What else to try when no practical number of such trials would show an effect."""
        return "run other plans"

    def outcome_only_note(self) -> str:
        """Why a log of outcomes alone cannot vouch for a cause."""
        return (f"the log records only the {self.outcome}, so an effect outside the registry that moves it alike cannot be "
                "excluded (record more signals to confirm the cause)")


def default_model() -> TrialModel:
    """The diagnosis model of the default task (:data:`besdrake.task.DEFAULT_TASK`)."""
    from besdrake.task import DEFAULT_TASK, get_task

    return get_task(DEFAULT_TASK).diagnosis_model()


def model_for(scenario) -> TrialModel:
    """The diagnosis model of ``scenario``'s task (a :class:`~besdrake.task.TaskError`, a ValueError, when the task
    has none)."""
    from besdrake.task import DEFAULT_TASK, get_task

    return get_task(getattr(scenario, "task", None) or DEFAULT_TASK).diagnosis_model()


__all__ = ["Observable", "SignalNoise", "PlacementScatter", "TrialModel", "default_model", "model_for"]
