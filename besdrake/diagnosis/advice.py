"""What would separate two fitted candidates: an unmeasured signal, or which throws differ most."""

from __future__ import annotations

from typing import Any

import numpy as np

from besdrake.diagnosis import fitting, noise, observables
from besdrake.diagnosis.observables import group_slices
from besdrake.diagnosis.simulate import _Sim


def _separation_advice(a: fitting.CandidateFit, b: fitting.CandidateFit, sim: _Sim, measured: list[str], plans_meta: list[dict]) -> dict:
    """Which unmeasured signal or which of the logged throws separates two fitted candidates most."""
    ya = sim.full_cache.get(sim.key(a.parameters()))
    yb = sim.full_cache.get(sim.key(b.parameters()))
    advice: dict[str, Any] = {"a": a.name, "b": b.name, "signals": []}
    if ya is None or yb is None:
        return advice
    sl = group_slices()
    for g, s in sl.items():
        d = np.abs(ya[:, s] - yb[:, s])
        if not np.isfinite(d).any():
            continue
        typ = noise.TYPICAL[g]
        score = float(np.nanmax(d) / typ)
        advice["signals"].append({"group": g, "measured": g in measured, "max_difference": float(np.nanmax(d)), "unit": observables.GROUP_UNITS[g], "in_noise_sd": score})
    advice["signals"].sort(key=lambda x: -x["in_noise_sd"])
    td = np.linalg.norm(ya[:, sl["touchdown"]] - yb[:, sl["touchdown"]], axis=1)
    if np.isfinite(td).any():
        i = int(np.nanargmax(td))
        advice["most_separating_throw"] = {"index": i, "touchdown_difference_m": float(td[i]), "plan": plans_meta[i]}
    unmeasured = [s for s in advice["signals"] if not s["measured"] and s["in_noise_sd"] > 3]
    if unmeasured:
        best = unmeasured[0]
        advice["recommendation"] = f"{_RECORD[best['group']]}: the fitted candidates differ by up to {best['max_difference']:.3g} {best['unit']} there (~{best['in_noise_sd']:.0f} x typical noise)"
    else:
        advice["recommendation"] = ("throw plans that spread the release speed and height more widely (e.g. amplitudes outside the logged range, other accelerations) "
                                    "and repeat each several times: the fitted candidates predict nearly the same signals for the logged throws")
        if "most_separating_throw" in advice:
            advice["recommendation"] += f"; the largest logged difference is {advice['most_separating_throw']['touchdown_difference_m'] * 100:.1f} cm (throw {i})"
    return advice


_RECORD = {"ball_pos": "record the ball path (motion capture)", "ball_vel": "record the ball path (motion capture): the release speed/direction",
           "ball_acc": "record the ball path (motion capture): the in-flight deceleration", "joints": "record the joint encoders (tracking error)",
           "touchdown": "measure the touchdown", "ball_rest": "record the ball in the scoop before the throw (motion capture)"}
