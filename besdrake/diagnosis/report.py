"""Write a :class:`~besdrake.diagnosis.core.Diagnosis` to a folder: ``report.md``, ``diagnosis.json``, the refined
scenario YAML (loads with :func:`besdrake.sim.load_scenario`) and PNG figures.

Figures: ``<outcome>s.png`` (lab vs nominal vs refined outcome per trial, e.g. ``touchdowns.png``), ``residuals.png``
(outcome disparity per trial before the fit, after it, and held out), ``groups.png`` (mean sim-vs-lab residual per
feature group in noise units, before and after). The words (a trial's noun, the outcome's name) and the per-trial
table's extra columns are the task's (:class:`~besdrake.diagnosis.trials.TrialModel`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml

from besdrake._io import save_figure as _save_figure, write_text as _atomic_write_text
from besdrake.diagnosis.core import EXCLUDE_FRACTION, Diagnosis
from besdrake.diagnosis.trials import TrialModel, model_for


def _model(diag: Diagnosis) -> TrialModel:
    """The diagnosed task's trial model."""
    return model_for(diag.scenario)


def _fmt_param(p: dict) -> str:
    bound = " (at its bound)" if p["at_bound"] else ""
    if not p.get("constrained", True):
        bound += " (not determined by these data)"
    return f"{p['effect']}.{p['parameter']} = {p['value']:.4g} +- {p['stderr']:.2g} {p['unit']}{bound}"


def write_refined_scenario(diag: Diagnosis, path: str | Path) -> Path:
    """Write the refined scenario YAML and check that it loads."""
    from besdrake.sim.scenario import load_scenario

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    d = diag.refined_scenario()
    _atomic_write_text(path, "# Written by besdrake diagnose: the scenario with the fitted effect(s). Units: SI (m, s, rad, kg).\n" + yaml.safe_dump(d, sort_keys=False))
    load_scenario(path)  # raises ScenarioError naming the field if anything is off
    return path


def _figures(diag: Diagnosis, out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    o = _model(diag).outcome
    rows = [r for r in diag.per_trial if r.get(f"{o}_measured") is not None]
    if rows:
        lab = np.array([r[f"{o}_measured"] for r in rows])
        nom = np.array([r[f"{o}_nominal"] for r in rows])
        ref = np.array([r[f"{o}_refined"] for r in rows])
        fig, ax = plt.subplots(figsize=(7, 6))
        for a, b in zip(nom, lab):
            ax.plot([a[0], b[0]], [a[1], b[1]], color="0.8", lw=0.8, zorder=1)
        ax.scatter(lab[:, 0], lab[:, 1], s=22, c="k", label="lab (measured)", zorder=3)
        ax.scatter(nom[:, 0], nom[:, 1], s=22, marker="x", c="tab:red", label="nominal simulation", zorder=2)
        if diag.best and diag.best.effects:
            ax.scatter(ref[:, 0], ref[:, 1], s=22, marker="+", c="tab:blue", label=f"refined ({' + '.join(diag.best.effects)})", zorder=2)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(f"{o.capitalize()}: lab vs simulation")
        ax.legend(loc="best", fontsize=8)
        fig.tight_layout()
        _save_figure(fig, out / f"{o}s.png", dpi=110)
        plt.close(fig)
        files.append(f"{o}s.png")

        fig, ax = plt.subplots(figsize=(8, 4))
        trials = [r["trial"] for r in rows]
        before = [r.get(f"{o}_error_before", np.nan) for r in rows]
        after = [r.get(f"{o}_error_after_fit", np.nan) for r in rows]
        held = [np.nan if r.get(f"{o}_heldout_disparity_after") is None else r[f"{o}_heldout_disparity_after"] for r in rows]
        x = np.arange(len(rows))
        ax.bar(x - 0.27, before, 0.27, label="nominal", color="tab:red")
        ax.bar(x, after, 0.27, label="refined (fit on all)", color="tab:blue")
        ax.bar(x + 0.27, held, 0.27, label="refined (held out)", color="tab:green")
        ax.axhline(diag.noise.sd[o] * np.sqrt(2 * np.log(2)), color="k", ls="--", lw=0.8, label="median disparity of pure noise")
        ax.set_xticks(x)
        ax.set_xticklabels([str(t) for t in trials], fontsize=6)
        ax.set_xlabel("trial")
        ax.set_ylabel(f"{o} disparity (m)")
        ax.legend(fontsize=7)
        fig.tight_layout()
        _save_figure(fig, out / "residuals.png", dpi=110)
        plt.close(fig)
        files.append("residuals.png")
    if diag.comparison:
        fig, ax = plt.subplots(figsize=(7, 3.5))
        names = [g.group for g in diag.comparison]
        z = [np.max(np.abs(np.array(g.mean)) / np.array(g.stderr)) for g in diag.comparison]
        ax.bar(names, z, color="tab:red")
        ax.axhline(3.0, color="k", ls="--", lw=0.8, label="3 standard errors")
        ax.set_ylabel("largest |mean residual| / SE")
        ax.set_title("Systematic error of the nominal simulation per signal")
        ax.legend(fontsize=8)
        fig.tight_layout()
        _save_figure(fig, out / "groups.png", dpi=110)
        plt.close(fig)
        files.append("groups.png")
    return files


def _md_comparison(diag: Diagnosis) -> list[str]:
    """Section 1: the nominal replay against the lab, per signal and per trial, and the noise."""
    model = _model(diag)
    o, n = model.outcome, model.noun
    L: list[str] = []
    L += ["", "## 1. What the simulation gets wrong (nominal replay of every logged plan)", ""]
    L.append(f"| signal | {n}s | mean residual (lab - sim) | SE | RMS | noise SD | systematic |")
    L.append("|---|---|---|---|---|---|---|")
    for g in diag.comparison:
        mean = ", ".join(f"{v:.3g}" for v in g.mean[:3]) + (" ..." if len(g.mean) > 3 else "")
        L.append(f"| {g.group} ({g.unit}) | {g.n_trials} | {mean} | {g.stderr[0]:.2g} | {g.rms:.3g} | {g.noise_sd:.3g} | {'yes' if g.systematic else 'no'} |")
    L.append("")
    cols = model.details_columns()
    L.append(f"Per {n} (lab vs nominal simulation" + (f"; {model.details_note}" if model.details_note else "") + "):")
    L.append("")
    L.append(f"| trial | {o} disparity nominal (m) | after fit (m) | held out (m) |" + "".join(f" {c[0]} |" for c in cols))
    L.append("|---|---|---|---|" + "---|" * len(cols))

    def f(r, k, scale=1.0, fmt=".3f"):
        v = r.get(k)
        return "-" if v is None else format(v * scale, fmt)

    for r in diag.per_trial:
        L.append(f"| {r['trial']} | {f(r, f'{o}_error_before')} | {f(r, f'{o}_error_after_fit')} | {f(r, f'{o}_heldout_disparity_after')} |"
                 + "".join(f" {f(r, key + '_lab', sc, fmt)} / {f(r, key + '_nominal', sc, fmt)} |" for _h, key, sc, fmt in cols))
    L.append("")
    L.append("Measurement noise per signal (never read from the lab's configuration):")
    for g, src in diag.noise.source.items():
        L.append(f"- {g}: SD {diag.noise.sd[g]:.3g} ({src})")
    axis = diag.noise.axis_sd()
    if axis:
        what = model.scatter.short if model.scatter is not None else "placement"
        L.append(f"- the fit weighs every {n} by its own SD: the scatter its {what} gives it in simulation, times a scale, "
                 "plus a base SD, both fitted to the repeats per axis: " + "; ".join(f"{g} " + ", ".join(f"{k.replace('_placement_scale', ' scale')} {v:.3g}" for k, v in d.items()) for g, d in axis.items()))
    return L


def _md_causes(diag: Diagnosis) -> list[str]:
    """Section 2: the candidates ranked by BIC and what cannot be told apart."""
    L: list[str] = []
    L += ["", "## 2. The cause: candidates ranked by BIC", ""]
    L.append("| rank | candidate | delta BIC | lack-of-fit p | fitted parameters (+- 1 SE) |")
    L.append("|---|---|---|---|---|")
    for i, c in enumerate(diag.causes[:10]):
        name = " + ".join(c.effects) if c.effects else "none (nominal)"
        pv = "n/a (linearised)" if not c.refined else f"{c.p_value:.3g}"
        params = "; ".join(_fmt_param(p) for p in c.parameters) or "-"
        L.append(f"| {i + 1} | {name} | {c.delta_bic:.1f} | {pv} | {params} |")
    L.append("")
    if diag.indistinguishable:
        L.append("### Causes the logged signals cannot tell apart")
        for a in diag.indistinguishable:
            if a.get("structural"):
                L.append(f"- **{a['a']}** and **{a['b']}** are the same cause: {a['reason']}.")
            else:
                L.append(f"- cannot tell **{a['a']}** from **{a['b']}** (delta BIC {a['delta_bic']:.1f}). To separate them: {a.get('recommendation', '')}.")
        L.append("")
    if diag.structural:
        L.append("### Structurally identical candidate parameters (no experiment separates them)")
        for c in diag.structural:
            L.append(f"- {c['reason']}")
        L.append("")
    return L


def _md_residual(diag: Diagnosis) -> list[str]:
    """Not explained: where the residual lives, and the residual model (offered or not)."""
    L: list[str] = []
    o = _model(diag).outcome
    if diag.residual:
        r = diag.residual
        L.append("### Not explained: where the residual lives")
        L.append("- share of the chi-square by observable: " + ", ".join(f"{g} {v:.0%}" for g, v in sorted(r["group_share"].items(), key=lambda x: -x[1])))
        L.append("- largest residuals: " + ", ".join(f"trial {w['trial']} ({w['plan']}, chi2 {w['chi2']:.0f})" for w in r["worst_trials"]))
        if r["follows"]:
            L.append(f"- the {o} residual follows: " + ", ".join(f"{f['axis']} ~ {f['feature']} (r = {f['r']:.2f})" for f in r["follows"][:4]))
        m = r.get("model", {})
        if m.get("heldout_after_m") is not None:
            figs = (f"held-out median {o} disparity {m['heldout_before_m'] * 100:.1f} -> {m['heldout_after_m'] * 100:.1f} cm "
                    f"({m['n_heldout']} held-out predictions, {m['folds']}-fold by plan x {m.get('repeats', 1)}, the choice of features refitted in every fold)")
            if m.get("offered"):
                L.append(f"- {m['label']}, on {', '.join(m['fit']['features']) or 'a constant offset'}: {figs}")
            else:
                L.append(f"- no gain: no data-driven residual model lowers the {o} disparity on held-out plans ({figs}); none offered")
        L.append("")
    return L


def _md_cannot_tell(diag: Diagnosis) -> list[str]:
    """No discrepancy beyond the noise: what the log cannot exclude; the unconstrained and the verdict's caveat."""
    L: list[str] = []
    if diag.cannot_tell:
        L.append("### No discrepancy beyond the noise: what the log cannot exclude")
        L.append("")
        L.append("The nominal simulation passes the lack-of-fit test, but that does not show it is right: these effects are still allowed "
                 "(99% likelihood-ratio intervals of each parameter on its own, on the linearised model, within the realistic bounds; "
                 "pairs that hide each other below the table):")
        L.append("")
        L.append(f"| effect | allowed values | largest allowed deviation (share of the range) | constrained by the log | {_model(diag).noun}s to exclude it | what would show it |")
        L.append("|---|---|---|---|---|---|")
        for a in diag.cannot_tell:
            vals = "; ".join(f"{k} {lo:.3g}..{hi:.3g} {a.units.get(k, '')}" for k, (lo, hi) in a.allowed.items())
            con = "no: (nearly) any realistic value fits" if a.unconstrained else "partly: larger deviations would have been seen"
            L.append(f"| {a.effect} | {vals} | {a.max_fraction:.0%} | {con} | {a.trials_needed if a.trials_needed is not None else 'no number'} | {a.recommendation} |")
        L.append("")
        if diag.excluded:
            L.append(f"Excluded (every deviation of {EXCLUDE_FRACTION:.0%} of the realistic range or more is ruled out, each alone): "
                     + ", ".join(a.effect for a in diag.excluded) + ".")
            L.append("")
        L += _md_hiding(list(diag.cannot_tell) + list(diag.excluded))
    unobs = diag.best.unobservable if diag.best else []
    if unobs:
        L.append(f"Parameters of the best candidate the data do not constrain (left at nominal): {', '.join(unobs)}.")
    if not diag.explained:
        L.append("**Not explained**: no candidate brings the residual down to the noise level. An effect outside the registry "
                 "(or a combination of more than two) is at work; the refined scenario below is only the best available approximation.")
    return L


def _md_hiding(allowed: list) -> list[str]:
    """The pairs of deviations that hide each other (``AllowedEffect.beside``): each parameter's wider interval and the
    partner that compensates, the most widened first; nothing where there are none."""
    rows = [(w, f"| {a.effect}.{name} | {a.allowed[name][0]:.3g}..{a.allowed[name][1]:.3g} | {other} | {lo:.3g}..{hi:.3g} {a.units.get(name, '')} |")
            for a in allowed for w, name, other, (lo, hi) in a.hiding_pairs()]
    if not rows:
        return []
    L = ["Two deviations can hide each other: the intervals above hold for each parameter alone; with a second one "
         "moving to compensate (within its realistic bounds, linearised) the log allows these:", "",
         "| parameter | alone | with | allowed together |", "|---|---|---|---|"]
    L += [r for _w, r in sorted(rows, key=lambda x: -x[0])]
    return L + [""]


def _md_refined(diag: Diagnosis, scenario_path: Path | None) -> list[str]:
    """Sections 3 and 4: the refined model and its held-out gain."""
    model = _model(diag)
    o, n = model.outcome, model.noun
    L: list[str] = []
    L += ["", "## 3. Refined model", ""]
    L.append(f"Scenario file: `{scenario_path}`" if scenario_path else "No refined scenario written.")
    L.append("")
    L.append("```yaml\neffects: " + json.dumps(diag.refined_effects()) + "\n```")
    L += ["", f"## 4. The gain ({n}s held out from the fit)", ""]
    if diag.gain:
        g = diag.gain
        if g.folds:
            L.append(f"{g.folds}-fold cross-validation by plan: every {n} is predicted by a model fitted without its plan ({g.n_heldout} {n}s); "
                     f"each fold's fit starts from the all-data optimum and is refitted on its training {n}s.")
        else:
            L.append("No effect fitted: the refined model is the nominal one (before = after).")
        L.append("")
        L.append(f"| | median {o} disparity | 95% CI (bootstrap) |")
        L.append("|---|---|---|")
        L.append(f"| before (nominal) | {g.median_disparity_before_m:.3f} m | {g.ci_before_m[0]:.3f}-{g.ci_before_m[1]:.3f} m |")
        L.append(f"| after (refined) | {g.median_disparity_after_m:.3f} m | {g.ci_after_m[0]:.3f}-{g.ci_after_m[1]:.3f} m |")
        L.append("")
        floor = diag.noise.sd[o] * np.sqrt(2 * np.log(2))
        L.append(f"Median disparity of pure measurement noise (from the noise estimate): {floor:.3f} m.")
    else:
        L.append(f"No held-out gain computed (no cause fitted or too few {o}s).")
    return L


def _md_notes(diag: Diagnosis, figures: list[str], s: dict) -> list[str]:
    """Figures and notes."""
    L: list[str] = []
    L += ["", "## Figures", ""]
    for f in figures:
        L.append(f"![{f}]({f})")
    L += ["", "## Notes", ""]
    for n in diag.notes:
        L.append(f"- {n}")
    L.append(f"- {diag.n_rollouts} rollouts in {s['timings_s']['total']:.1f} s ({', '.join(f'{k} {v:.1f} s' for k, v in s['timings_s'].items() if k != 'total')}).")
    return L


def _markdown(diag: Diagnosis, figures: list[str], scenario_path: Path | None) -> str:
    s = diag.summary()
    L = ["# Diagnosis of the simulation against the lab log", ""]
    L.append(f"**Verdict:** {diag.verdict}.  ")
    L.append(f"**Explained:** {'yes' if diag.explained else 'no'} (confidence: {diag.confidence}).")
    L.append("")
    L.append(f"Trials in the log: {diag.n_trials}; compared: {diag.n_used}; skipped: {len(diag.skipped)}. Signals measured: {', '.join(diag.groups_measured)}.")
    L += _md_comparison(diag) + _md_causes(diag) + _md_residual(diag) + _md_cannot_tell(diag)
    L += _md_refined(diag, scenario_path) + _md_notes(diag, figures, s)
    return "\n".join(L) + "\n"


def write_report(diag: Diagnosis, out: str | Path, figures: bool = True) -> dict[str, str]:
    """Write ``report.md``, ``diagnosis.json``, ``refined_scenario.yaml`` and figures into ``out``; returns the paths."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    scen = write_refined_scenario(diag, out / "refined_scenario.yaml")
    diag.refined_scenario_path = str(scen)
    figs = _figures(diag, out) if figures else []
    _atomic_write_text(out / "diagnosis.json", diag.to_json())
    per_trial = out / f"per_{_model(diag).noun}.json"
    _atomic_write_text(per_trial, json.dumps(diag.per_trial, indent=1))
    _atomic_write_text(out / "report.md", _markdown(diag, figs, scen))
    return {"report": str(out / "report.md"), "json": str(out / "diagnosis.json"), "scenario": str(scen), "per_trial": str(per_trial), **{f: str(out / f) for f in figs}}


__all__ = ["write_report", "write_refined_scenario"]
