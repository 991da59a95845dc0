"""Border placement rules learned from a labelled subject, applied after vMCI.

vMCI finds where the segment model changes; a human annotator also follows conventions of
their own: a recording's first segment begins at its first frame (a leading pause is part of
it), a short pause between two movements is one border, a movement ends where its speed has
dropped to a fraction of its peak rather than where it reaches zero, a shallow dip inside a
movement is no border. :class:`BorderRules` states these conventions as a few numbers and
:func:`apply_rules` applies them to a :class:`~besdrake.segmentation.vmci.VMCIResult`;
:func:`learn_rules` chooses the numbers on labelled recordings (one subject) by an exhaustive
search over a small grid, to be applied unchanged to other recordings.

The rules, in the order they are applied, on the segments and their models ("movement" /
"rest"):

1. ``merge_end_rests``: a rest segment at the start (end) of the recording is merged into the
   segment after (before) it, so its border goes.
2. ``pause_s`` / ``pause_speed``: every interior stretch where the hand speed stays below
   ``pause_speed`` (m/s) for at least ``pause_s`` seconds and that no rest segment of the
   inference overlaps becomes a rest segment (the borders inside it go, one border at each
   end; rule 6 then moves them to the speed levels). The scored border definition counts
   both ends of a pause (:data:`~besdrake.segmentation.evaluation.BORDER_DEFINITION`); vMCI
   sometimes explains a pause by the tails of two bell-shaped movements instead.
3. ``dip_ratio``: a border between two movement segments is dropped when the speed there is
   above ``dip_ratio`` times the smaller of the two segments' peak speeds (no real minimum).
4. ``min_rest_s``: an interior rest segment shorter than this becomes a single border at its
   speed minimum.
5. ``snap_s``: a border between two movement segments moves to the lowest speed within
   ``snap_s`` seconds.
6. ``end_level`` / ``start_level``: a movement -> rest border moves back to where the speed
   drops below ``end_level`` times the movement's peak speed; a rest -> movement border moves
   forward to where it rises above ``start_level`` times the peak (each at most half the
   movement segment away).

A value of 0 (or False) switches a rule off (``pause_speed`` only matters with ``pause_s``).
"""

from __future__ import annotations

import itertools
from dataclasses import asdict, dataclass, fields

import numpy as np

from besdrake.segmentation.base import SegmentationResult


@dataclass(frozen=True)
class BorderRules:
    """Border placement conventions (see the module docstring); 0 / False switches a rule off."""

    merge_end_rests: bool = False
    dip_ratio: float = 0.0
    min_rest_s: float = 0.0
    snap_s: float = 0.0
    end_level: float = 0.0
    start_level: float = 0.0
    pause_s: float = 0.0
    pause_speed: float = 0.05

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name != "merge_end_rests" and not (np.isfinite(v) and v >= 0):
                raise ValueError(f"BorderRules.{f.name} must be a number >= 0, got {v!r}")
        if self.pause_s > 0 and self.pause_speed <= 0:
            raise ValueError(f"BorderRules.pause_speed must be > 0 (m/s) when pause_s is set, got {self.pause_speed}")
        for name in ("end_level", "start_level"):
            if getattr(self, name) >= 1:
                raise ValueError(f"BorderRules.{name} is a fraction of the peak speed (< 1), got {getattr(self, name)}")

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "BorderRules":
        names = {f.name for f in fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"unknown BorderRules fields {sorted(unknown)}; valid: {sorted(names)}")
        return cls(**d)

    @property
    def is_identity(self) -> bool:
        """True when no rule is switched on (``pause_speed`` alone does nothing)."""
        from dataclasses import replace

        return replace(self, pause_speed=BorderRules.pause_speed) == BorderRules()


#: The pause rule (``pause_s`` / ``pause_speed``) as measured on the pick-and-place data: the hand
#: at rest is slower than 5 cm/s, and 0.4 s is vMCI's own shortest rest segment
#: (``rest_min_length_s``). Manual borders within 0.2 s of the interior stretches below 5 cm/s:
#: subject 2's annotator draws two at both stretches of 0.4 s or more and one (or none) at 29 of
#: the 30 shorter ones; subject 1's draws two at 21 of 28 and at 5 of 17. Not a default (see
#: ``scripts/bench_segmentation.py``, variant ``vmci_rules_pause``).
PAUSE_RULE = {"pause_s": 0.4, "pause_speed": 0.05}

#: The grid :func:`learn_rules` searches by default (2 * 4 * 4 * 3 * 5 * 4 = 1920 rule sets).
#: Each list runs from the rule switched off to its strongest setting (for ``dip_ratio`` a
#: lower ratio drops more borders), so that ties go to the weaker rule.
DEFAULT_RULE_GRID = {
    "merge_end_rests": [False, True],
    "dip_ratio": [0.0, 0.7, 0.5, 0.3],
    "min_rest_s": [0.0, 0.3, 0.45, 0.6],
    "snap_s": [0.0, 0.1, 0.2],
    "end_level": [0.0, 0.05, 0.1, 0.15, 0.2],
    "start_level": [0.0, 0.05, 0.1, 0.2],
}


def apply_rules(result: SegmentationResult, speed: np.ndarray, frequency: float, rules: BorderRules):
    """A copy of ``result`` with its borders placed by ``rules`` (``segment_models`` updated).

    ``speed``: ``(n_samples,)`` hand speed the segmentation was computed on; ``result`` needs
    ``segment_models`` (one "movement" / "rest" per segment; missing means all movement).
    """
    from dataclasses import replace

    speed = np.asarray(speed, dtype=float)
    n = result.n_samples
    if speed.shape != (n,):
        raise ValueError(f"speed has shape {speed.shape}, the segmentation has {n} samples")
    edges = [0, *[int(b) for b in result.borders], n - 1]
    models = list(getattr(result, "segment_models", None) or ["movement"] * (len(edges) - 1))
    if len(models) != len(edges) - 1:
        raise ValueError(f"{len(models)} segment models for {len(edges) - 1} segments")
    if rules.merge_end_rests:
        _merge_end_rests(edges, models)
    if rules.pause_s > 0:
        edges, models = _insert_pauses(edges, models, speed, frequency, rules)
    if rules.dip_ratio > 0:
        _drop_borders_without_dip(edges, models, speed, rules.dip_ratio)
    if rules.min_rest_s > 0:
        _collapse_short_rests(edges, models, speed, rules.min_rest_s * frequency)
    if rules.snap_s > 0:
        _snap_to_minima(edges, models, speed, int(round(rules.snap_s * frequency)))
    _borders_at_levels(edges, models, speed, rules)
    borders, models = _increasing(np.array(edges[1:-1], dtype=int), models, n)
    out = replace(result, borders=borders, n_samples=n)
    if hasattr(out, "segment_models"):
        out.segment_models = models
    return out


def _peak(speed: np.ndarray, edges: list[int], i: int) -> float:
    """Peak speed of segment ``i``."""
    return float(speed[edges[i]:edges[i + 1] + 1].max())


def _merge_end_rests(edges: list[int], models: list[str]) -> None:
    """Rule 1: rests at the recording's ends belong to the first / last segment (in place)."""
    if len(models) > 1 and models[0] == "rest":
        del edges[1], models[0]
    if len(models) > 1 and models[-1] == "rest":
        del edges[-2], models[-1]


def _drop_borders_without_dip(edges: list[int], models: list[str], speed: np.ndarray, dip_ratio: float) -> None:
    """Rule 3: no border between two movements without a real dip (speed there below ``dip_ratio`` of the smaller
    peak; in place)."""
    i = 1
    while i < len(edges) - 1:
        if models[i - 1] == models[i] == "movement" and speed[edges[i]] > dip_ratio * min(_peak(speed, edges, i - 1), _peak(speed, edges, i)):
            del edges[i], models[i]
        else:
            i += 1


def _collapse_short_rests(edges: list[int], models: list[str], speed: np.ndarray, min_samples: float) -> None:
    """Rule 4: a rest shorter than ``min_samples`` becomes one border, at its speed minimum (in place)."""
    i = 1
    while i < len(models) - 1:
        a, b = edges[i], edges[i + 1]
        if models[i] == "rest" and b - a < min_samples:
            m = a + int(np.argmin(speed[a:b + 1]))
            edges[i:i + 2] = [m]
            del models[i]
        else:
            i += 1


def _snap_to_minima(edges: list[int], models: list[str], speed: np.ndarray, w: int) -> None:
    """Rule 5: a border between two movements moves to the speed minimum within ``w`` samples (in place)."""
    for i in range(1, len(edges) - 1):
        if models[i - 1] == models[i] == "movement":
            lo, hi = max(edges[i - 1] + 1, edges[i] - w), min(edges[i + 1] - 1, edges[i] + w)
            if hi >= lo:
                edges[i] = lo + int(np.argmin(speed[lo:hi + 1]))


def _borders_at_levels(edges: list[int], models: list[str], speed: np.ndarray, rules: BorderRules) -> None:
    """Rule 6: a movement ends / starts where its speed crosses ``end_level`` / ``start_level`` of its peak, searched
    over the half of the segment next to the border (in place)."""
    for i in range(1, len(edges) - 1):
        left, right = models[i - 1], models[i]
        if left == "movement" and right == "rest" and rules.end_level > 0:
            a, b = edges[i - 1], edges[i]
            thr = rules.end_level * _peak(speed, edges, i - 1)
            j, stop = b, max(a + 1, b - (b - a) // 2)
            while j > stop and speed[j - 1] < thr:
                j -= 1
            edges[i] = j
        elif left == "rest" and right == "movement" and rules.start_level > 0:
            b, c = edges[i], edges[i + 1]
            thr = rules.start_level * _peak(speed, edges, i)
            j, stop = b, min(c - 1, b + (c - b) // 2)
            while j < stop and speed[j] < thr:
                j += 1
            edges[i] = j


def _increasing(borders: np.ndarray, models: list[str], n: int) -> tuple[np.ndarray, list[str]]:
    """Where a rule made two borders cross, keep the unique increasing ones (and their segments' models)."""
    if np.all(np.diff(np.r_[0, borders, n - 1]) > 0):
        return borders, models
    keep = np.r_[True, np.diff(borders) > 0] if len(borders) else np.array([], bool)
    return borders[keep], [models[0], *[m for m, k in zip(models[1:], keep) if k]]


def _low_runs(low: np.ndarray) -> list[tuple[int, int]]:
    """``(first, last)`` sample of every run of True in ``low``."""
    d = np.diff(np.r_[0, low.astype(int), 0])
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1))


def _insert_pauses(edges: list[int], models: list[str], speed: np.ndarray, frequency: float, rules: BorderRules):
    """Edges and models with every interior pause of the speed a rest segment of its own (rule 2)."""
    n = len(speed)
    starts = list(zip(edges[:-1], models))  # (first sample, model) of every segment
    for a, b in _low_runs(speed < rules.pause_speed):
        if a == 0 or b >= n - 1 or b - a + 1 < rules.pause_s * frequency:
            continue
        ends = [e for e, _ in starts[1:]] + [n - 1]
        overlapped = [m for (s, m), e in zip(starts, ends) if s <= b and e > a]
        if "rest" in overlapped:
            continue
        after = [m for s, m in starts if s <= b][-1]  # the model the pause interrupts
        starts = sorted([(s, m) for s, m in starts if not a <= s <= b] + [(a, "rest"), (b, after)])
    return [s for s, _ in starts] + [n - 1], [m for _, m in starts]


@dataclass
class RuleCase:
    """One labelled recording for :func:`learn_rules`: a segmentation, its speed and the manual borders."""

    result: SegmentationResult
    speed: np.ndarray
    frequency: float
    true_borders: np.ndarray  # sample indices


@dataclass
class LearnedRules:
    """The rules chosen by :func:`learn_rules` and their score on the training cases."""

    rules: BorderRules
    f1: dict  # tolerance_s -> F1 on the training cases
    objective: float
    n_candidates: int
    identity_f1: dict  # the same scores without rules

    def to_dict(self) -> dict:
        return {"rules": self.rules.to_dict(), "f1": {str(k): v for k, v in self.f1.items()},
                "objective": self.objective, "n_candidates": self.n_candidates,
                "identity_f1": {str(k): v for k, v in self.identity_f1.items()}}


def rule_grid(spec: dict | None = None):
    """Every :class:`BorderRules` of a grid ``{field: [values]}`` (default :data:`DEFAULT_RULE_GRID`)."""
    spec = DEFAULT_RULE_GRID if spec is None else spec
    keys = list(spec)
    for vals in itertools.product(*spec.values()):
        yield BorderRules(**dict(zip(keys, vals)))


def score_cases(cases: list[RuleCase], rules: BorderRules, tolerances=(0.1, 0.2)) -> dict:
    """Border F1 over all cases (pooled counts) after applying ``rules``, per tolerance."""
    from besdrake.segmentation.evaluation import match_borders

    matched = {t: 0 for t in tolerances}
    n_pred = n_true = 0
    for c in cases:
        pred = apply_rules(c.result, c.speed, c.frequency, rules).borders
        n_pred += len(pred)
        n_true += len(c.true_borders)
        for t in tolerances:
            matched[t] += match_borders(pred, c.true_borders, t * c.frequency)
    out = {}
    for t in tolerances:
        out[t] = 2 * matched[t] / (n_pred + n_true) if n_pred + n_true else 0.0
    return out


def learn_rules(cases: list[RuleCase], grid: dict | None = None, tolerances=(0.1, 0.2)) -> LearnedRules:
    """Choose the :class:`BorderRules` of ``grid`` with the best mean F1 over ``tolerances`` on
    ``cases`` (ties: the earlier grid point; in :data:`DEFAULT_RULE_GRID` order, the weaker rules)."""
    if not cases:
        raise ValueError("learn_rules needs at least one labelled case")
    best = None
    count = 0
    for rules in rule_grid(grid):
        count += 1
        f1 = score_cases(cases, rules, tolerances)
        obj = float(np.mean(list(f1.values())))
        if best is None or obj > best[0] + 1e-12:
            best = (obj, rules, f1)
    identity = score_cases(cases, BorderRules(), tolerances)
    return LearnedRules(best[1], best[2], best[0], count, identity)
