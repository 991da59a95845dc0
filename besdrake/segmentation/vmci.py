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
* Segment length prior: geometric with mean ``mean_length_s`` (a per-segment penalty),
  truncated below ``min_length_s``.
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


@dataclass
class _LengthTables:
    """Per-length tables: polynomial coefficients of the basis and posterior matrices."""

    n_basis: int
    delta2: float
    dt: float
    coef: list = field(default_factory=list)  # L -> (K, deg+1) coefficients in u (seconds)
    post: list = field(default_factory=list)  # L -> (K, K) posterior matrix M_L
    logdet: list = field(default_factory=list)  # L -> 0.5 * (log|M_L| - K log delta2)

    @property
    def degree(self) -> int:
        return 4 + self.n_basis - 1

    def grow(self, upto: int) -> None:
        P = np.polynomial.polynomial
        K = self.n_basis
        while len(self.coef) <= upto:
            L = len(self.coef)
            if L == 0:
                self.coef.append(np.zeros((K, self.degree + 1)))
                self.post.append(np.eye(K) * self.delta2)
                self.logdet.append(0.0)
                continue
            T = L * self.dt
            base = P.polymul(P.polymul([0, 0, 1.0], [T, -1.0]), [T, -1.0])  # u^2 (T-u)^2
            rows = []
            for k in range(K):
                c = P.polymul(base, P.polypow([-T, 2.0], k)) * 16.0 / T ** (4 + k)
                rows.append(np.pad(c, (0, self.degree + 1 - len(c))))
            coef = np.array(rows)
            u = (np.arange(L) + 0.5) * self.dt
            phi = np.stack([P.polyval(u, c) for c in coef], axis=1)  # (L, K)
            A = phi.T @ phi + np.eye(K) / self.delta2
            M = np.linalg.inv(A)
            sign, ld = np.linalg.slogdet(M)
            self.coef.append(coef)
            self.post.append(M)
            self.logdet.append(0.5 * (ld - K * np.log(self.delta2)))
        return None


@dataclass
class VMCIResult(SegmentationResult):
    """A segmentation by :class:`VMCI` plus its inference statistics."""

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
        min_length_s: shortest segment (seconds).
        max_length_s: longest segment (seconds); particles older than this are dropped.
        max_particles: particles kept after each step.
        prune_log_ratio: particles whose path log-probability is lower than the best by more
            than this are pruned.
        frequency: sampling rate (Hz) used when ``fit`` gets a plain array.
        velocity_window_s: Savitzky-Golay window for velocities computed from positions.
        input: ``"position"`` (arrays are positions, velocities are computed) or
            ``"velocity"`` (arrays are velocities already).

    After :meth:`fit`: ``result_`` (:class:`VMCIResult`), ``borders_`` (interior border sample
    indices), ``segments_`` (``(start, end)`` index pairs, adjacent segments share a border).
    """

    def __init__(
        self,
        n_basis: int = 2,
        noise_ratio: float = 0.1,
        weight_ratio: float = 3.0,
        nu: float = 4.0,
        mean_length_s: float = 1.5,
        min_length_s: float = 0.25,
        max_length_s: float = 8.0,
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
        self.max_length_s = max_length_s
        self.max_particles = max_particles
        self.prune_log_ratio = prune_log_ratio
        self.frequency = frequency
        self.velocity_window_s = velocity_window_s
        self.input = input

    # ------------------------------------------------------------------ checks
    def _check_params(self) -> None:
        if int(self.n_basis) != self.n_basis or not 1 <= self.n_basis <= 4:
            raise ValueError(f"n_basis must be an integer in 1..4, got {self.n_basis}")
        for name in ("noise_ratio", "weight_ratio", "nu", "mean_length_s", "min_length_s", "max_length_s", "frequency"):
            val = getattr(self, name)
            if not (np.isfinite(val) and val > 0):
                raise ValueError(f"{name} must be a positive number, got {val}")
        if self.max_length_s <= self.min_length_s:
            raise ValueError(f"max_length_s ({self.max_length_s}) must exceed min_length_s ({self.min_length_s})")
        if self.max_particles < 1:
            raise ValueError(f"max_particles must be >= 1, got {self.max_particles}")
        if self.input not in ("position", "velocity"):
            raise ValueError(f"input must be 'position' or 'velocity', got {self.input!r}")

    # ------------------------------------------------------------------ core
    def segment_velocity(self, V: np.ndarray, frequency: float) -> VMCIResult:
        """Segment a velocity time series ``V`` of shape ``(n, d)`` sampled at ``frequency`` Hz."""
        self._check_params()
        V = np.asarray(V, dtype=float)
        if V.ndim == 1:
            V = V[:, None]
        n, d = V.shape
        dt = 1.0 / frequency
        lmin = max(2, int(round(self.min_length_s * frequency)))
        lmax = int(round(self.max_length_s * frequency))
        if n < 2 * lmin:
            raise SegmentationError(
                f"a recording of {n} samples ({n * dt:.3g} s) is too short to segment: "
                f"at least {2 * lmin} samples (two segments of min_length_s={self.min_length_s} s) are needed"
            )
        if not np.isfinite(V).all():
            bad = np.flatnonzero(~np.isfinite(V).all(axis=1))
            raise SegmentationError(
                f"the input has NaN/inf at {len(bad)} samples (first index {bad[0]}); "
                "fill gaps first (besdrake.mocap.preprocess.fill_gaps) or crop the recording"
            )
        scale = float(np.sqrt(np.mean(np.sum(V**2, axis=1))))
        if scale <= 0:
            # no motion at all: one segment
            return VMCIResult(borders=np.array([], dtype=int), n_samples=n, log_posterior=0.0,
                              mean_particles=1.0, max_particles_used=1)
        V = V / scale  # unit RMS speed: the priors below are relative to the data
        K = int(self.n_basis)
        nu = float(self.nu)
        gamma = nu * self.noise_ratio**2  # prior mean of sigma^2 ~ gamma / nu (relative units)
        delta2 = (self.weight_ratio / self.noise_ratio) ** 2
        tables = _LengthTables(K, delta2, dt)
        tables.grow(min(lmax, n) + 1)
        deg = tables.degree
        post = np.array(tables.post)  # (Lmax+1, K, K)
        coef = np.array(tables.coef)  # (Lmax+1, K, deg+1)
        logdet = np.array(tables.logdet)
        p = 1.0 / max(self.mean_length_s * frequency, 1.0 + 1e-9)
        log_pen = np.log(p) - np.log1p(-p)  # per-segment log prior (geometric, up to a constant)
        lg_nu = gammaln(nu / 2) - 0.5 * nu * np.log(gamma)

        sq = np.sum(V**2, axis=1)
        csq = np.r_[0.0, np.cumsum(sq)]

        Vbest = np.full(n + 1, -np.inf)
        Vbest[0] = 0.0
        back = np.zeros(n + 1, dtype=int)
        # particle state: start index, moments (P, deg+1, d)
        starts = np.array([0], dtype=int)
        mom = np.zeros((1, deg + 1, d))
        powers = np.arange(deg + 1)
        n_used = []
        for t in range(1, n + 1):
            v = V[t - 1]
            u = (t - 1 - starts + 0.5) * dt  # time of sample t-1 since each particle's start
            mom += (u[:, None] ** powers)[:, :, None] * v[None, None, :]
            L = t - starts
            b = np.einsum("pkm,pmd->pkd", coef[L], mom)  # Phi^T v  (P, K, d)
            quad = np.einsum("pkd,pkj,pjd->p", b, post[L], b)
            rss = np.maximum(csq[t] - csq[starts] - quad, 0.0)
            N = L * d
            loglik = (
                -0.5 * N * np.log(np.pi)
                - lg_nu
                - 0.5 * (N + nu) * np.log(gamma + rss)
                + gammaln(0.5 * (N + nu))
                + d * logdet[L]
            )
            score = Vbest[starts] + loglik + log_pen
            ok = L >= lmin
            if ok.any():
                cand = np.where(ok, score, -np.inf)
                j = int(np.argmax(cand))
                Vbest[t] = cand[j]
                back[t] = starts[j]
            # prune: keep young particles, the best by score, within the ratio
            if t < n:
                keep = L < lmax
                mature = keep & ok
                if mature.sum() > 0:
                    best = score[mature].max()
                    keep &= ~ok | (score >= best - self.prune_log_ratio)
                    if (keep & ok).sum() > self.max_particles:
                        thr = np.sort(score[keep & ok])[-self.max_particles]
                        keep &= ~ok | (score >= thr)
                starts = starts[keep]
                mom = mom[keep]
                if np.isfinite(Vbest[t]):
                    starts = np.r_[starts, t]
                    mom = np.concatenate([mom, np.zeros((1, deg + 1, d))], axis=0)
                if len(starts) == 0:
                    raise SegmentationError("all particles were pruned; raise max_particles or max_length_s")
                n_used.append(len(starts))
        if not np.isfinite(Vbest[n]):
            raise SegmentationError("no segmentation satisfies the length limits; lower min_length_s")
        borders = []
        t = n
        while t > 0:
            s = back[t]
            if s > 0:
                borders.append(s)
            t = s
        return VMCIResult(
            borders=np.array(sorted(borders), dtype=int),
            n_samples=n,
            log_posterior=float(Vbest[n]),
            mean_particles=float(np.mean(n_used)) if n_used else 1.0,
            max_particles_used=int(max(n_used)) if n_used else 1,
        )

    def _segment(self, V: np.ndarray, frequency: float) -> VMCIResult:
        return self.segment_velocity(V, frequency)
