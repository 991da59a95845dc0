"""What would separate two fitted candidates: an unmeasured signal, or which trials differ most."""

from __future__ import annotations

from typing import Any

import numpy as np

from besdrake.diagnosis import fitting
from besdrake.diagnosis.simulate import _Sim


def _separation_advice(a: fitting.CandidateFit, b: fitting.CandidateFit, sim: _Sim, measured: list[str], plans_meta: list[dict]) -> dict:
    """Which unmeasured signal or which of the logged trials separates two fitted candidates most."""
    ya = sim.full_cache.get(sim.key(a.parameters()))
    yb = sim.full_cache.get(sim.key(b.parameters()))
    advice: dict[str, Any] = {"a": a.name, "b": b.name, "signals": []}
    if ya is None or yb is None:
        return advice
    model = sim.model
    sl, typical, units = model.slices(), model.typical(), model.units()
    for g, s in sl.items():
        d = np.abs(ya[:, s] - yb[:, s])
        if not np.isfinite(d).any():
            continue
        score = float(np.nanmax(d) / typical[g])
        advice["signals"].append({"group": g, "measured": g in measured, "max_difference": float(np.nanmax(d)), "unit": units[g], "in_noise_sd": score})
    advice["signals"].sort(key=lambda x: -x["in_noise_sd"])
    out = sl[model.outcome]
    td = np.linalg.norm(ya[:, out] - yb[:, out], axis=1)
    diff_key = f"{model.outcome}_difference_m"
    if np.isfinite(td).any():
        i = int(np.nanargmax(td))
        advice["most_separating_trial"] = {"index": i, diff_key: float(td[i]), "plan": plans_meta[i]}
    unmeasured = [s for s in advice["signals"] if not s["measured"] and s["in_noise_sd"] > 3]
    if unmeasured:
        best = unmeasured[0]
        advice["recommendation"] = (f"{model.group(best['group']).record}: the fitted candidates differ by up to {best['max_difference']:.3g} {best['unit']} "
                                    f"there (~{best['in_noise_sd']:.0f} x typical noise)")
    else:
        advice["recommendation"] = model.spread_advice()
        if "most_separating_trial" in advice:
            advice["recommendation"] += f"; the largest logged difference is {advice['most_separating_trial'][diff_key] * 100:.1f} cm ({model.noun} {i})"
    return advice
