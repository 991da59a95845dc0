"""The throwing task's learn stage 10, ``report``: report.md with the paper's Table 1 and this run's times, every
stage's figures and meshcat replays."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from besdrake._io import write_text as _atomic_write_text
from besdrake.pipeline.learn import Context, fmt_time as _fmt_time
from besdrake.tasks.throwing.learn.transfer import refined_scenario


#: Paper Table 1, per experiment of 8 throws: (stage, time in s, automated, required knowledge); every stage before the
#: report, in the order they run.
PAPER_TABLE_1: dict[str, tuple[str, float | None, str, str]] = {
    "label": ("Automatic marker labeling", 4 * 60 + 58, "yes", "Neighboring markers, initial pose"),
    "segment": ("Behavior segmentation + movement classification", 44 + 2, "yes", "labelled training throws (classification)"),
    "imitate": ("Imitation learning", 4 * 60 + 20, "yes", "Robot description"),
    "refine": ("Policy search", 10 * 60, "yes", "Reward function, simulation"),
    "transfer": ("Transferability approach", 75 * 60, "(yes)", "Reward function, simulation"),
    "diagnose": ("Simulation refinement (paper: grid search on height and release angle)", None, "yes", "effect registry"),
    "transfer_refined": ("Transferability approach after refinement", None, "(yes)", "Reward function, refined simulation"),
    "template": ("Behavior template learning (paper: 80 episodes on the robot)", None, "yes", "Reward function, context space"),
    "pool": ("Behavior template pool", None, "yes", "-"),
}



def stage_report(ctx: Context, out: Path) -> dict[str, Any]:
    """report.md: the paper's Table 1 with this run's times, every stage's figures, replays."""
    from besdrake.plan import MotionPlan
    from besdrake.sim.record import record_html

    root = ctx.run.root
    done = {name: ctx.run.done(i, name) for i, name in enumerate(PAPER_TABLE_1, 1)}  # every stage before this one
    n_exp = max(1, len(done["label"]["summary"]["recordings"])) if done.get("label") else 1
    replays = []
    for stage, folder in (("transfer_refined", "07_transfer_refined"), ("transfer", "05_transfer")):
        plan_file = root / folder / "best.plan.json"
        if plan_file.is_file():
            scenario = refined_scenario(ctx) if stage == "transfer_refined" else ctx.config["scenario"]
            html, _ = record_html(MotionPlan.load(plan_file), out / f"best_throw_{stage}.html", scenario=scenario, limits="flag", host=ctx.meshcat_host)
            replays.append(html.name)
    lines = [
        "# besdrake learn: report",
        "",
        f"Run folder `{root}`; configuration in `config.yaml`. Times are wall-clock on this machine; the paper's are per "
        f"experiment of 8 throws (this run: {n_exp} experiment(s)).",
        "",
        "## Table 1: each stage, its time, whether it ran without a person, what it needed",
        "",
        "| stage | this run | per experiment | paper (per experiment) | automated | required knowledge |",
        "|---|---|---|---|---|---|",
    ]
    per_experiment = {"label", "segment", "imitate"}
    for name in PAPER_TABLE_1:
        rec = done.get(name)
        title, paper_s, automated, knowledge = PAPER_TABLE_1[name]
        seconds = rec["seconds"] if rec else None
        per = _fmt_time(seconds / n_exp) if (rec and name in per_experiment) else "-"
        lines.append(f"| {title} | {_fmt_time(seconds) if rec else 'not run'} | {per} | {_fmt_time(paper_s)} | {automated} | {knowledge} |")
    lines += ["", "Manual steps of the paper that a virtual lab needs no person for: attaching markers (0:55 min), motion capture "
              "(1:08 min), manual marker labeling (9:19 min), labelling the classifier's training set (50 min, done once).", ""]
    sections = {
        "label": ("Automatic marker labeling", "01_label"),
        "segment": ("Segmentation and classification", "02_segment"),
        "imitate": ("Imitation (embodiment mapping, DMP)", "03_imitate"),
        "refine": ("Policy search in simulation", "04_refine"),
        "transfer": ("Transferability Approach, designed simulation", "05_transfer"),
        "diagnose": ("Diagnosis: what the simulation gets wrong", "06_diagnose"),
        "transfer_refined": ("Transferability Approach, refined simulation", "07_transfer_refined"),
        "template": ("Behaviour template", "08_template"),
        "pool": ("Template pool", "09_pool"),
    }
    for name, (title, folder) in sections.items():
        rec = done.get(name)
        lines += [f"## {title}", ""]
        if rec is None:
            lines += ["Not run.", ""]
            continue
        summary = {k: v for k, v in rec["summary"].items() if not isinstance(v, (list, dict)) or k in ("gain",)}
        lines += ["| key | value |", "|---|---|"] + [f"| {k} | {_short(v)} |" for k, v in summary.items()] + [""]
        if name == "template":
            lines += _reach_lines(rec["summary"].get("reach_refinement") or {})
        for png in sorted((root / folder).glob("*.png"))[:2] + sorted((root / folder).glob("*/*.png"))[:3]:
            lines.append(f"![{png.stem}]({png.relative_to(root).as_posix()})")
        lines.append("")
    lines += _workers_table(done)
    if replays:
        lines += ["## Replays", ""] + [f"- [{r}](10_report/{r}) (meshcat, self-contained HTML)" for r in replays] + [""]
    _atomic_write_text(root / "report.md", "\n".join(lines))
    return {"report": str(root / "report.md"), "replays": replays}


def _reach_lines(reach: dict[str, Any]) -> list[str]:
    """report.md's account of the template's base: each reach refinement towards the far target (from where, how close,
    in how many episodes), each candidate base's reach floor over the test contexts, and which base was kept."""
    if not reach.get("target_m"):
        return []
    target = ", ".join(f"{v:g}" for v in reach["target_m"])
    runs = [("the refined throw", reach)] + [(f"{r['from']} (another refinement run)", r) for r in reach.get("other_runs") or []]
    others = reach.get("other_families") or ([reach["other_family"]] if reach.get("other_family") else [])  # one: before session 46
    runs += [(f"the imitated throws of start group {r['start_group']}", r) for r in others]
    lines = [f"Reach refinements towards ({target}) m:", ""]
    for where, r in runs:
        if r.get("best_distance_m") is not None:
            lines.append(f"- from {where}: {r['start_distance_m']:.3f} -> {r['best_distance_m']:.3f} m in {r['episodes']} episodes")
    floors = " / ".join(f"{100 * f:.1f}" for f in reach.get("floor_m") or [])
    kept = reach.get("kept_from") or "refined throw"
    lines += ["", f"Template base kept: {kept}" + (f" (reach floors over the test contexts, refined throw first: {floors} cm)" if floors else "") + ".", ""]
    return lines


def _workers_table(done: dict[str, Any]) -> list[str]:
    """report.md's table of each simulating stage's rollouts, the workers' busy share and the batches' width."""
    rows = [(name, rec["summary"]["executor"]) for name, rec in done.items() if rec and rec["summary"].get("executor")]
    if not rows:
        return []
    lines = ["## Rollouts and workers", "",
             "Busy share: of the workers' time while simulating and over the whole stage. Width: rollouts per batch (what a "
             "larger pool could run at once); fill: the share of a 16- or 64-worker pool those batches could keep busy at best.", "",
             "| stage | workers | rollouts | rollouts/s | busy (simulating / stage) | batches | width mean / max | fill 16 / 64 |",
             "|---|---|---|---|---|---|---|---|"]
    for name, ex in rows:
        lines.append(f"| {name} | {ex['workers']} | {ex['rollouts']} | {ex['rollouts_per_s']} | {_short(ex['busy_share'])} / "
                     f"{_short(ex.get('stage_busy_share'))} | {ex.get('batches', '-')} | {ex.get('width_mean', '-')} / {ex.get('width_max', '-')} | "
                     f"{ex.get('fill_16_workers', '-')} / {ex.get('fill_64_workers', '-')} |")
    return lines + [""]


def _short(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, dict):
        return ", ".join(f"{k}: {_short(v)}" for k, v in value.items())
    return str(value)
