"""Measurement noise per observable group, estimated from the log itself (never from the lab's config).

Preferred source: *pure error* from repeated plans (trials of the same plan, matched by content hash):
the pooled within-plan variance of every feature of a group. It contains everything that varies from
throw to throw (ball placement in the scoop, marker noise, encoder noise) and nothing systematic, so it is
the noise floor the simulation can at best reach. Without repeats the touchdown noise falls back to the
paper's figure (good throws repeat with 4.5-7 cm SD) and the other groups to what the signals themselves
show (marker noise from the ballistic-fit residuals, encoder noise from second differences); the result
says so (``source``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from besdrake.diagnosis.observables import N_JOINT_TIMES, group_names, group_slices

#: Touchdown SD per axis (m) assumed when the log has no repeated plans (paper: 4.5-7 cm for good throws).
PRIOR_TOUCHDOWN_SD = 0.05
#: Smallest SD per group: what a simulation can be trusted to reproduce (2.5 ms step, linearisation; joint tracking
#: of a simulated servo is not accurate to better than ~1 mrad even when the encoders are finer).
FLOORS = {"touchdown": 0.003, "ball_pos": 0.002, "ball_vel": 0.01, "ball_acc": 0.05, "joints": 1e-3}
#: Typical noise of a group that the log does not contain (used only to judge what *would* separate causes).
TYPICAL = {"touchdown": 0.05, "ball_pos": 0.01, "ball_vel": 0.05, "ball_acc": 0.3, "joints": 1e-3}
#: Minimum degrees of freedom of the pure error before it is trusted.
MIN_DOF = 4


@dataclass
class NoiseModel:
    """SD per group (in the group's unit), the degrees of freedom of each estimate (0: assumed/derived)
    and where it came from."""

    sd: dict[str, float]
    dof: dict[str, int]
    source: dict[str, str]
    n_repeat_groups: int = 0
    notes: list[str] = field(default_factory=list)

    def vector(self) -> np.ndarray:
        """SD per feature (length of a feature vector)."""
        sl = group_slices()
        out = np.empty(sl[group_names()[-1]].stop)
        for g, s in sl.items():
            out[s] = self.sd[g]
        return out

    def to_dict(self) -> dict:
        return {"sd": dict(self.sd), "dof": dict(self.dof), "source": dict(self.source), "n_repeat_groups": self.n_repeat_groups, "notes": list(self.notes)}


def pure_error(features: np.ndarray, keys: list[str]) -> dict[str, tuple[float, int]]:
    """Pooled within-plan SD and its dof per group, from rows of ``features`` sharing a key."""
    sl = group_slices()
    out: dict[str, tuple[float, int]] = {}
    by_key: dict[str, list[int]] = {}
    for i, k in enumerate(keys):
        by_key.setdefault(k, []).append(i)
    groups = [idx for idx in by_key.values() if len(idx) > 1]
    for g, s in sl.items():
        ss, dof, n_feat = 0.0, 0, s.stop - s.start
        for idx in groups:
            block = features[idx][:, s]
            rows = block[np.all(np.isfinite(block), axis=1)]
            if len(rows) < 2:
                continue
            ss += float(np.sum((rows - rows.mean(axis=0)) ** 2))
            dof += (len(rows) - 1) * n_feat
        if dof > 0:
            # The group's SD pools all its features (same unit, similar scale); dof counts every feature.
            out[g] = (float(np.sqrt(ss / dof)), dof)
    return out


def estimate_noise(features: np.ndarray, keys: list[str], mocap_sd: float | None, encoder_sd: float | None, ball_sd_from_fit: dict[str, float] | None = None) -> NoiseModel:
    """Noise per group from repeated plans where possible, else priors and signal-derived values."""
    pe = pure_error(features, keys)
    n_rep = len({k for k in keys if keys.count(k) > 1})
    sd, dof, source, notes = {}, {}, {}, []
    for g in group_names():
        if g in pe and pe[g][1] >= MIN_DOF:
            sd[g], dof[g], source[g] = pe[g][0], pe[g][1], f"repeated plans ({pe[g][1]} dof)"
        elif g == "touchdown":
            sd[g], dof[g], source[g] = PRIOR_TOUCHDOWN_SD, 0, "assumed (paper: 4.5-7 cm SD; the log repeats no plan)"
            notes.append("no repeated plans: touchdown noise assumed 5 cm; repeat some plans to measure it")
        elif g == "joints" and encoder_sd is not None:
            sd[g], dof[g], source[g] = encoder_sd, 0, "encoder noise from second differences"
        elif g.startswith("ball") and ball_sd_from_fit and g in ball_sd_from_fit:
            sd[g], dof[g], source[g] = ball_sd_from_fit[g], 0, "marker noise propagated through the flight fit"
        else:
            sd[g], dof[g], source[g] = TYPICAL[g], 0, "typical value (not measured)"
        if sd[g] < FLOORS[g]:
            sd[g] = FLOORS[g]
            source[g] += f"; raised to the simulation floor {FLOORS[g]:g}"
    return NoiseModel(sd=sd, dof=dof, source=source, n_repeat_groups=n_rep, notes=notes)


def ball_fit_sd(layout_times: list[np.ndarray], centers: list[float], mocap_sd: float | None) -> dict[str, float]:
    """SD of the flight-fit coefficients (position, velocity, acceleration) for marker noise ``mocap_sd``."""
    if mocap_sd is None:
        return {}
    vals = []
    for t, tc in zip(layout_times, centers):
        if t is None:
            continue
        s = t - tc
        A = np.column_stack([np.ones_like(s), s, 0.5 * s * s])
        vals.append(np.sqrt(np.diag(np.linalg.inv(A.T @ A))) * mocap_sd)
    if not vals:
        return {}
    v = np.median(np.array(vals), axis=0)
    return {"ball_pos": float(v[0]), "ball_vel": float(v[1]), "ball_acc": float(v[2])}


__all__ = ["NoiseModel", "estimate_noise", "pure_error", "ball_fit_sd", "PRIOR_TOUCHDOWN_SD", "N_JOINT_TIMES"]
