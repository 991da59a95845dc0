"""Zero-velocity-crossing baseline segmenter.

Borders at the local minima of the hand speed that fall below ``threshold`` times the
recording's 95th-percentile speed (a near-zero-velocity crossing), at least ``min_gap_s``
apart (of two close candidates the slower one is kept). The classic baseline of
movement segmentation (e.g. Fod, Mataric & Jenkins 2002), used here for comparison with vMCI.
"""

from __future__ import annotations

import numpy as np

from besdrake.segmentation.base import SegmentationError, SegmenterMixin, result_from_borders


class ZeroVelocitySegmenter(SegmenterMixin):
    """Borders at near-zero minima of the speed.

    Args:
        threshold: a speed minimum is a border if below ``threshold * percentile95(speed)``.
        min_gap_s: minimum time between borders (s).
        smooth_s: moving-average window (s) applied to the speed before finding minima.
        frequency, velocity_window_s, input, signal: as for :class:`~besdrake.segmentation.VMCI`.
    """

    def __init__(
        self,
        threshold: float = 0.2,
        min_gap_s: float = 0.3,
        smooth_s: float = 0.0,
        frequency: float = 60.0,
        velocity_window_s: float = 0.15,
        input: str = "position",
        signal: str = "hand_velocity",
    ) -> None:
        self.threshold = threshold
        self.min_gap_s = min_gap_s
        self.smooth_s = smooth_s
        self.frequency = frequency
        self.velocity_window_s = velocity_window_s
        self.input = input
        self.signal = signal

    def _segment(self, V: np.ndarray, frequency: float):
        n = len(V)
        if n < 3:
            raise SegmentationError(f"a recording of {n} samples is too short to segment")
        speed = np.linalg.norm(V, axis=1)
        w = int(round(self.smooth_s * frequency))
        if w > 1:
            speed = np.convolve(speed, np.ones(w) / w, mode="same")
        ref = np.percentile(speed, 95)
        if ref <= 0:
            return result_from_borders([], n)
        interior = np.arange(1, n - 1)
        is_min = (speed[interior] <= speed[interior - 1]) & (speed[interior] < speed[interior + 1])
        cand = interior[is_min & (speed[interior] < self.threshold * ref)]
        gap = max(1, int(round(self.min_gap_s * frequency)))
        chosen: list[int] = []
        for c in cand[np.argsort(speed[cand], kind="stable")]:
            if all(abs(c - k) >= gap for k in chosen):
                chosen.append(int(c))
        return result_from_borders(chosen, n)
