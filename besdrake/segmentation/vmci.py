"""Velocity-based multiple changepoint inference (vMCI).

Senger et al. 2014 extend the Bayesian multiple changepoint inference of Fearnhead & Liu
2007 to human manipulation: every segment is a linear-regression model of the hand velocity
on a *bell-shaped* basis, so that the most probable segmentation cuts where the hand speed
passes through a minimum. This module implements that model from the papers:

* Segment model. For a segment of ``L`` samples (duration ``T``), with ``u`` the time since
  the segment start (sample midpoints) and ``tau = u / T``, each velocity dimension is
  ``v(u) = sum_k w_k phi_k(tau) + noise`` with
  ``phi_k(tau) = 16 tau^2 (1 - tau)^2 (2 tau - 1)^k`` for ``k < n_basis``. Every basis
  function vanishes with zero slope at both ends: a segment starts and ends at rest
  (minimum-jerk-like bell for k = 0, skew for k = 1). The noise variance ``sigma^2`` of a
  segment is unknown, shared by the dimensions, with an inverse-gamma prior
  ``IG(nu/2, gamma/2)``; the weights have the prior ``N(0, sigma^2 delta^2 I)`` (the
  conjugate model of Fearnhead 2006), so the segment's marginal likelihood is closed-form.
  (``noise_model="shared"``: a known noise variance instead.)
* Open ends: the first and last segment may start / end at a non-zero velocity (the
  recording may be cropped mid-movement): two cubic ramps join their basis there.
* Rest model: as Fearnhead & Liu allow several models per segment, a segment may instead
  be a *rest* (velocity zero plus noise with its own, smaller prior noise level
  ``rest_noise_ratio``), so pauses become segments of their own (both ends of a pause are
  borders). ``segment_models`` in the result says which model won per segment.
* Segment length prior: geometric with mean ``mean_length_s`` (a per-segment penalty),
  truncated below ``min_length_s`` for movements and ``rest_min_length_s`` for rests.
* Border rules (:mod:`besdrake.segmentation.placement`) may move or drop borders after the
  inference: by default a border between two movements without a real speed dip is dropped;
  rules learned from a labelled subject place borders the way its annotator does.
* Inference: the online Viterbi recursion of Fearnhead & Liu 2007,
  ``V[t] = max_s V[s] + log P(v[s:t] | segment) + log g(t - s)``, over a set of candidate
  last changepoints (particles) that is pruned at every step (particles whose path
  probability falls below ``prune_log_ratio`` of the best, then the ``max_particles``
  best are kept). The regression statistics of every particle are updated in O(1) per
  sample from running polynomial moments, so a step costs O(particles).
* Parameters from the data: the velocity scale is the recording's RMS hand speed; the
  noise prior mean is ``noise_ratio`` times that scale and the weight prior spans
  ``weight_ratio`` times it. No value is tuned per recording.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.special import gammaln

from besdrake.segmentation.base import (
    SegmentationError,
    SegmentationResult,
    SegmenterMixin,
    result_from_borders,
)
from besdrake.segmentation.placement import BorderRules, apply_rules

#: Rules applied by default: drop a border between two movements where the speed has no real
#: dip (above 0.7 of the smaller peak), the counterpart of the short ``min_length_s``.
DEFAULT_RULES = BorderRules(dip_ratio=0.7)


class _LengthTables:
    """Per-length tables of the segment basis: polynomial coefficients and posterior matrices.

    Basis ``k < n_bells``: bells; then two cubic Hermite ramps (velocity 1 -> 0 and 0 -> 1 with
    zero slope at both ends) that let a segment start / end at a non-zero velocity. A ramp is
    used with prior variance ``ramp_var[0]`` (start) / ``ramp_var[1]`` (end) relative to
    sigma^2, or left out where that variance is 0 (its row of ``coef`` and of the posterior is
    then zero). Four variants: index ``open_start + 2 * open_end`` where an open end of the
    recording uses ``open_var`` instead of the interior ramp variance.
    """

    def __init__(self, n_bells: int, bell_var: float, ramp_var: float, open_var: float, dt: float, upto: int):
        self.n_bells = n_bells
        self.K = n_bells + 2
        self.degree = max(4 + n_bells - 1, 3)
        self.dt = dt
        n = upto + 1
        D = self.degree + 1
        coef = np.zeros((n, self.K, D))
        for L in range(1, n):
            coef[L] = self.polynomials(L * dt)
        # Gram matrices from power sums: G[L]_kj = sum_ab c_ka c_jb S_{a+b}(L),
        # S_m(L) = sum_{i<L} u_i^m with u_i = (i + 1/2) dt (vectorised over all lengths)
        u = (np.arange(n - 1) + 0.5) * dt
        powers = u[:, None] ** np.arange(2 * D - 1)[None, :]
        S = np.vstack([np.zeros((1, 2 * D - 1)), np.cumsum(powers, axis=0)])  # (n, 2D-1)
        idx = np.arange(D)[:, None] + np.arange(D)[None, :]
        gram = np.einsum("lka,ljb,lab->lkj", coef, coef, S[:, idx])
        self.coef = np.zeros((4, n, self.K, D))
        self.post = np.zeros((4, n, self.K, self.K))
        self.logdet = np.zeros((4, n))
        for variant in range(4):
            var = np.r_[
                np.full(n_bells, bell_var),
                open_var if variant & 1 else ramp_var,
                open_var if variant & 2 else ramp_var,
            ]
            used = np.flatnonzero(var > 0)
            A = gram[1:][:, used][:, :, used] + np.diag(1.0 / var[used])[None]
            M = np.linalg.inv(A)
            _, ld = np.linalg.slogdet(M)
            self.coef[variant, 1:, used] = np.moveaxis(coef[1:, used], 1, 0)
            sub = self.post[variant, 1:]
            sub[:, used[:, None], used[None, :]] = M
            self.logdet[variant, 1:] = 0.5 * (ld - np.sum(np.log(var[used])))

    def polynomials(self, T: float) -> np.ndarray:
        """``(K, degree+1)`` coefficients in ``u`` (seconds) of the basis for a segment of duration T."""
        P = np.polynomial.polynomial
        rows = []
        base = P.polymul(P.polymul([0, 0, 1.0], [T, -1.0]), [T, -1.0])  # u^2 (T-u)^2
        for k in range(self.n_bells):
            rows.append(P.polymul(base, P.polypow([-T, 2.0], k)) * 16.0 / T ** (4 + k))
        rows.append(np.array([1.0, 0.0, -3.0 / T**2, 2.0 / T**3]))
        rows.append(np.array([0.0, 0.0, 3.0 / T**2, -2.0 / T**3]))
        return np.array([np.pad(c, (0, self.degree + 1 - len(c))) for c in rows])


@dataclass(frozen=True)
class _Lengths:
    """Segment length limits in samples: a movement's and a rest's shortest, the shortest of any model, the length
    from which a particle may be pruned, and the longest."""

    move: int
    rest: int
    shortest: int
    mature: int
    longest: int


def _check_series(V: np.ndarray, frequency: float, lmin: int, min_length_s: float) -> None:
    """:class:`SegmentationError` for a recording too short for two segments, or with NaN/inf samples."""
    n, dt = V.shape[0], 1.0 / frequency
    if n < 2 * lmin:
        raise SegmentationError(
            f"a recording of {n} samples ({n * dt:.3g} s) is too short to segment: "
            f"at least {2 * lmin} samples (two segments of {lmin} samples, min_length_s={min_length_s} s) are needed"
        )
    if not np.isfinite(V).all():
        bad = np.flatnonzero(~np.isfinite(V).all(axis=1))
        raise SegmentationError(
            f"the input has NaN/inf at {len(bad)} samples (first index {bad[0]}); "
            "fill gaps first (besdrake.mocap.gaps.fill_gaps) or crop the recording"
        )


def _backtrack(back: np.ndarray, kind: np.ndarray, n: int) -> tuple[np.ndarray, list[str]]:
    """The best segmentation's borders (sorted) and its segments' models, from the filter's back pointers."""
    borders, models = [], []
    t = n
    while t > 0:
        s = back[t]
        models.append("rest" if kind[t] else "movement")
        if s > 0:
            borders.append(s)
        t = s
    return np.array(sorted(borders), dtype=int), models[::-1]


@dataclass
class VMCIResult(SegmentationResult):
    """A segmentation by :class:`VMCI` plus its inference statistics."""

    segment_models: list = field(default_factory=list)  # "movement" or "rest", one per segment
    log_posterior: float = float("nan")
    mean_particles: float = float("nan")
    max_particles_used: int = 0


class VMCI(SegmenterMixin):
    """Velocity-based multiple changepoint inference with an online pruned Viterbi.

    Args:
        n_basis: bell-shaped basis functions per velocity dimension (1: symmetric bell,
            2: bell with skew/turn).
        noise_ratio: prior mean noise standard deviation, as a fraction of the RMS speed.
        weight_ratio: prior standard deviation of the basis weights, as a multiple of the RMS
            speed.
        nu: prior degrees of freedom of the noise variance.
        mean_length_s: mean of the geometric prior on segment duration (seconds).
        min_length_s: shortest movement segment (seconds).
        rest_min_length_s: shortest rest segment (seconds); None: ``min_length_s``. A short
            rest at a speed minimum is two borders where an annotator sees one, while a fast
            movement (e.g. a swing) may be much shorter than the pauses worth a segment.
        max_length_s: longest segment (seconds); particles older than this are dropped.
        boundary_ratio: if > 0, two cubic ramps let a segment start and end at a non-zero
            velocity, with a prior standard deviation of ``boundary_ratio`` times the RMS
            speed (small: borders are drawn to speed minima without requiring rest).
        noise_model: ``"segment"`` (unknown noise variance per segment, inverse-gamma prior)
            or ``"shared"`` (known noise variance ``(noise_ratio * RMS speed)^2``).
        rest_log_prior: log prior odds of the rest model against a movement segment; None
            disables the rest model.
        open_ends: let the first / last segment start / end at a non-zero velocity.
        rest_noise_ratio: prior mean noise level of rest segments, as a fraction of the RMS
            speed (None: ``noise_ratio``).
        rest_border_level: if set, a border between a movement and a rest segment is moved
            to where the speed crosses this fraction of the movement's peak speed
            (:func:`refine_rest_borders`); None keeps the model's borders.
        rules: border placement rules applied after inference
            (:class:`~besdrake.segmentation.placement.BorderRules` or its dict; None: none;
            default :data:`DEFAULT_RULES`), e.g. learned on a labelled subject by
            :func:`~besdrake.segmentation.tuning.tune_vmci`.
        max_particles: particles kept after each step.
        prune_log_ratio: particles whose path log-probability is lower than the best by more
            than this are pruned.
        frequency: sampling rate (Hz) used when ``fit`` gets a plain array.
        velocity_window_s: Savitzky-Golay window for velocities computed from positions.
        input: ``"position"`` (arrays are positions, velocities are computed) or
            ``"velocity"`` (arrays are velocities already).

    After :meth:`fit`: ``result_`` (:class:`VMCIResult`), ``borders_`` (interior border sample
    indices), ``segments_`` (``(start, end)`` index pairs, adjacent segments share a border).

    The defaults (noise_ratio 0.3, nu 10, rest_noise_ratio 0.25, rest_min_length_s 0.4) were
    chosen on subject 1 of the real pick-and-place data; min_length_s 0.15 lets a movement be as
    short as the fastest synthetic demonstrations (0.15 s; a 0.4 s minimum merged such a movement with its
    neighbour), and the default rules' dip criterion removes the spurious short splits that
    allows on the slow pick-and-place movements. ``scripts/bench_segmentation.py`` chooses the
    priors and rules on each subject (:func:`~besdrake.segmentation.tuning.tune_vmci`) and
    scores the other.
    """

    def __init__(
        self,
        n_basis: int = 2,
        noise_ratio: float = 0.3,
        weight_ratio: float = 3.0,
        nu: float = 10.0,
        mean_length_s: float = 1.5,
        min_length_s: float = 0.15,
        rest_min_length_s: float | None = 0.4,
        max_length_s: float = 8.0,
        boundary_ratio: float = 0.0,
        noise_model: str = "segment",
        rest_log_prior: float | None = 0.0,
        open_ends: bool = True,
        rest_noise_ratio: float | None = 0.25,
        rest_border_level: float | None = None,
        rules=DEFAULT_RULES,
        max_particles: int = 60,
        prune_log_ratio: float = 60.0,
        frequency: float = 60.0,
        velocity_window_s: float = 0.15,
        input: str = "position",
    ) -> None:
        self.n_basis = n_basis
        self.noise_ratio = noise_ratio
        self.weight_ratio = weight_ratio
        self.nu = nu
        self.mean_length_s = mean_length_s
        self.min_length_s = min_length_s
        self.rest_min_length_s = rest_min_length_s
        self.max_length_s = max_length_s
        self.boundary_ratio = boundary_ratio
        self.noise_model = noise_model
        self.rest_log_prior = rest_log_prior
        self.open_ends = open_ends
        self.rest_noise_ratio = rest_noise_ratio
        self.rest_border_level = rest_border_level
        self.rules = rules
        self.max_particles = max_particles
        self.prune_log_ratio = prune_log_ratio
        self.frequency = frequency
        self.velocity_window_s = velocity_window_s
        self.input = input

    # ------------------------------------------------------------------ checks
    def _check_params(self) -> None:
        if int(self.n_basis) != self.n_basis or not 1 <= self.n_basis <= 4:
            raise ValueError(f"n_basis must be an integer in 1..4, got {self.n_basis}")
        if not (np.isfinite(self.boundary_ratio) and self.boundary_ratio >= 0):
            raise ValueError(f"boundary_ratio must be >= 0, got {self.boundary_ratio}")
        for name in ("noise_ratio", "weight_ratio", "nu", "mean_length_s", "min_length_s", "max_length_s", "frequency"):
            val = getattr(self, name)
            if not (np.isfinite(val) and val > 0):
                raise ValueError(f"{name} must be a positive number, got {val}")
        if self.rest_min_length_s is not None and not (np.isfinite(self.rest_min_length_s) and 0 < self.rest_min_length_s < self.max_length_s):
            raise ValueError(f"rest_min_length_s must be positive and below max_length_s, got {self.rest_min_length_s}")
        if self.max_length_s <= self.min_length_s:
            raise ValueError(f"max_length_s ({self.max_length_s}) must exceed min_length_s ({self.min_length_s})")
        if self.max_particles < 1:
            raise ValueError(f"max_particles must be >= 1, got {self.max_particles}")
        if self.noise_model not in ("segment", "shared"):
            raise ValueError(f"noise_model must be 'segment' or 'shared', got {self.noise_model!r}")
        if self.input not in ("position", "velocity"):
            raise ValueError(f"input must be 'position' or 'velocity', got {self.input!r}")
        self._rules()

    def _rules(self):
        if self.rules is None or isinstance(self.rules, BorderRules):
            return self.rules
        if isinstance(self.rules, dict):
            return BorderRules.from_dict(self.rules)
        raise ValueError(f"rules must be a BorderRules, a dict of its fields or None, got {type(self.rules).__name__}")

    # ------------------------------------------------------------------ core
    def segment_velocity(self, V: np.ndarray, frequency: float) -> VMCIResult:
        """Segment a velocity time series ``V`` of shape ``(n, d)`` sampled at ``frequency`` Hz."""
        self._check_params()
        V = np.asarray(V, dtype=float)
        if V.ndim == 1:
            V = V[:, None]
        n = V.shape[0]
        lengths = self._lengths(frequency)
        _check_series(V, frequency, lengths.shortest, self.min_length_s)
        scale = float(np.sqrt(np.mean(np.sum(V**2, axis=1))))
        if scale <= 0:
            # no motion at all: one segment
            return VMCIResult(borders=np.array([], dtype=int), n_samples=n, log_posterior=0.0,
                              mean_particles=1.0, max_particles_used=1)
        V = V / scale  # unit RMS speed: the priors below are relative to the data
        Vbest, back, kind, n_used = self._forward(V, 1.0 / frequency, lengths, frequency)
        if not np.isfinite(Vbest[n]):
            raise SegmentationError("no segmentation satisfies the length limits; lower min_length_s")
        borders, models = _backtrack(back, kind, n)
        return VMCIResult(
            borders=borders,
            n_samples=n,
            segment_models=models,
            log_posterior=float(Vbest[n]),
            mean_particles=float(np.mean(n_used)) if n_used else 1.0,
            max_particles_used=int(max(n_used)) if n_used else 1,
        )

    def _lengths(self, frequency: float) -> "_Lengths":
        """The segment length limits in samples."""
        rest = self.rest_log_prior is not None
        move = max(2, int(round(self.min_length_s * frequency)))
        rest_min = move if self.rest_min_length_s is None else max(2, int(round(self.rest_min_length_s * frequency)))
        return _Lengths(move=move, rest=rest_min,
                        shortest=min(move, rest_min) if rest else move,  # shortest segment of any model
                        mature=max(move, rest_min) if rest else move,  # pruned only once every model may end
                        longest=int(round(self.max_length_s * frequency)))

    def _marginal(self):
        """The log marginal likelihood of a segment from its residual sum of squares: ``f(rss, N, logdet, rest)``."""
        nu, s2 = float(self.nu), self.noise_ratio**2
        gamma = nu * s2  # prior mean of sigma^2 ~ gamma / nu (relative units)
        lg_nu = gammaln(nu / 2) - 0.5 * nu * np.log(gamma)
        rest_ratio = self.rest_noise_ratio if self.rest_noise_ratio else self.noise_ratio
        gamma_rest = nu * rest_ratio**2
        lg_nu_rest = gammaln(nu / 2) - 0.5 * nu * np.log(gamma_rest)
        shared_noise = self.noise_model == "shared"

        def marginal(rss, N, logdet_term, rest_model=False):
            if shared_noise:
                var = rest_ratio**2 if rest_model else s2
                return -0.5 * N * np.log(2 * np.pi * var) - 0.5 * rss / var + logdet_term
            g, lg = (gamma_rest, lg_nu_rest) if rest_model else (gamma, lg_nu)
            return (
                -0.5 * N * np.log(np.pi)
                - lg
                - 0.5 * (N + nu) * np.log(g + rss)
                + gammaln(0.5 * (N + nu))
                + logdet_term
            )
        return marginal

    def _forward(self, V: np.ndarray, dt: float, lengths: "_Lengths", frequency: float):
        """The particle filter over segment starts: the best log posterior of a segmentation ending at each sample,
        the start of its last segment, whether that is a rest segment, and the particles in use per step."""
        n, d = V.shape
        rest = self.rest_log_prior is not None
        bell_var = (self.weight_ratio / self.noise_ratio) ** 2
        boundary_var = (self.boundary_ratio / self.noise_ratio) ** 2
        tables = _LengthTables(int(self.n_basis), bell_var, boundary_var, bell_var if self.open_ends else boundary_var,
                               dt, min(lengths.longest, n) + 1)
        deg, post, coef, logdet = tables.degree, tables.post, tables.coef, tables.logdet
        p = 1.0 / max(self.mean_length_s * frequency, 1.0 + 1e-9)
        log_pen = np.log(p) - np.log1p(-p)  # per-segment log prior (geometric, up to a constant)
        log_rest = float(self.rest_log_prior) if rest else 0.0
        marginal = self._marginal()
        csq = np.r_[0.0, np.cumsum(np.sum(V**2, axis=1))]
        Vbest = np.full(n + 1, -np.inf)
        Vbest[0] = 0.0
        back = np.zeros(n + 1, dtype=int)
        kind = np.zeros(n + 1, dtype=bool)  # True: the segment ending at t is a rest segment
        # particle state: start index, moments (P, deg+1, d)
        starts, mom, powers, n_used = np.array([0], dtype=int), np.zeros((1, deg + 1, d)), np.arange(deg + 1), []
        for t in range(1, n + 1):
            u = (t - 1 - starts + 0.5) * dt  # time of sample t-1 since each particle's start
            mom += (u[:, None] ** powers)[:, :, None] * V[t - 1][None, None, :]
            L = t - starts
            variant = (starts == 0) + (2 if t == n else 0)
            b = np.einsum("pkm,pmd->pkd", coef[variant, L], mom)  # Phi^T v  (P, K, d)
            quad = np.einsum("pkd,pkj,pjd->p", b, post[variant, L], b)
            rss = np.maximum(csq[t] - csq[starts] - quad, 0.0)
            score = Vbest[starts] + marginal(rss, L * d, d * logdet[variant, L]) + log_pen
            score = np.where(L >= lengths.move, score, -np.inf)
            is_rest = np.zeros(len(starts), dtype=bool)
            if rest:
                score_rest = Vbest[starts] + marginal(csq[t] - csq[starts], L * d, 0.0, rest_model=True) + log_pen + log_rest
                score_rest = np.where(L >= lengths.rest, score_rest, -np.inf)
                is_rest = score_rest > score
                score = np.where(is_rest, score_rest, score)
            if np.isfinite(score).any():
                j = int(np.argmax(score))
                Vbest[t], back[t], kind[t] = score[j], starts[j], is_rest[j]
            if t < n:
                keep = self._survivors(score, L, lengths)
                starts, mom = starts[keep], mom[keep]
                if np.isfinite(Vbest[t]):
                    starts = np.r_[starts, t]
                    mom = np.concatenate([mom, np.zeros((1, deg + 1, d))], axis=0)
                if len(starts) == 0:
                    raise SegmentationError("all particles were pruned; raise max_particles or max_length_s")
                n_used.append(len(starts))
        return Vbest, back, kind, n_used

    def _survivors(self, score: np.ndarray, L: np.ndarray, lengths: "_Lengths") -> np.ndarray:
        """Pruning: keep the young particles, and of the mature ones the best by score, within the ratio, at most
        ``max_particles``; none longer than the longest segment."""
        ok = L >= lengths.mature
        keep = L < lengths.longest
        mature = keep & ok
        if mature.sum() > 0:
            best = score[mature].max()
            keep &= ~ok | (score >= best - self.prune_log_ratio)
            if (keep & ok).sum() > self.max_particles:
                thr = np.sort(score[keep & ok])[-self.max_particles]
                keep &= ~ok | (score >= thr)
        return keep

    def _segment(self, V: np.ndarray, frequency: float) -> VMCIResult:
        result = self.segment_velocity(V, frequency)
        if self.rest_border_level is not None and "rest" in result.segment_models:
            result = refine_rest_borders(result, np.linalg.norm(V, axis=1), self.rest_border_level,
                                         int(round(self.min_length_s * frequency)))
        rules = self._rules()
        if rules is not None and not rules.is_identity:
            result = apply_rules(result, np.linalg.norm(V, axis=1), frequency, rules)
        return result


def refine_rest_borders(result: VMCIResult, speed: np.ndarray, level: float, max_shift: int) -> VMCIResult:
    """Move each border between a movement and a rest segment to where the speed crosses
    ``level`` times the movement segment's peak speed (the nearest crossing on the movement's
    side, at most ``max_shift`` samples away); other borders are kept.

    The segment model puts a movement's end where its bell has decayed to (almost) zero; a
    human annotator ends it where the speed has dropped to a fraction of its peak.
    """
    edges = [0, *[int(b) for b in result.borders], result.n_samples - 1]
    models = list(result.segment_models)
    new = list(edges)
    for i in range(1, len(edges) - 1):
        left, right = models[i - 1], models[i]
        if left == right:
            continue
        b = edges[i]
        if left == "movement":  # movement -> rest: last sample above the level, scanning back
            a0 = edges[i - 1]
            thr = level * speed[a0:b + 1].max()
            j = b
            while j > max(a0 + 1, b - max_shift) and speed[j] < thr:
                j -= 1
            new[i] = j + 1 if j < b else b
        else:  # rest -> movement: first sample above the level, scanning forward
            c = edges[i + 1]
            thr = level * speed[b:c + 1].max()
            j = b
            while j < min(c - 1, b + max_shift) and speed[j] < thr:
                j += 1
            new[i] = j
    # keep the borders strictly increasing
    for i in range(1, len(new) - 1):
        new[i] = min(max(new[i], new[i - 1] + 1), new[i + 1] - 1) if new[i + 1] - new[i - 1] > 1 else edges[i]
    result.borders = np.array(new[1:-1], dtype=int)
    return result
