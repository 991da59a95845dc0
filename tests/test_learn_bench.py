"""scripts/bench_learn.py: a subject's figures from its run folder, the summary over subjects, and its resume (a timed,
complete run folder is not run again; an untimed one is set aside and run afresh)."""

from __future__ import annotations

import json

STAGES = ("01_label", "02_segment", "03_imitate", "04_refine", "05_transfer", "06_diagnose", "07_transfer_refined",
          "08_template", "09_pool", "10_report")


def _fake_run(root, seconds: float, runs: list[tuple[int, float]], sim_m: float, lab_m: float) -> None:
    for folder in STAGES:
        (root / folder).mkdir(parents=True)
        summary = {}
        if folder == "04_refine":
            summary = {"runs": [{"n_episodes": n, "best_distance_within_limits_m": d, "stop_reason": "stalled"} for n, d in runs],
                       "executor": {"rollouts": 123}}
        if folder == "08_template":
            summary = {"sim_mean_distance_m": sim_m, "lab_mean_distance_m": lab_m, "reach_refinement": {"episodes": 40, "kept_from": "reach refinement"}}
        (root / folder / "stage.json").write_text(json.dumps({"seconds": seconds, "summary": summary}))


def test_rows_and_summary_from_run_folders(tmp_path, script):
    bench = script("bench_learn")
    _fake_run(tmp_path / "a", 10.0, [(850, 0.064), (690, 0.088)], 0.015, 0.066)
    _fake_run(tmp_path / "b", 5.0, [(1000, 0.13)], 0.03, 0.08)
    rows = [bench._row(0, tmp_path / "a", {"wall_s": 396.0, "cpu_s": 670.0, "returncode": 0}),
            bench._row(1, tmp_path / "b", {"wall_s": 200.0, "cpu_s": 300.0, "returncode": 0}),
            bench._row(2, tmp_path / "missing", {"wall_s": 3.0, "cpu_s": 1.0, "returncode": 1})]
    assert rows[0]["stage_s"]["refine"] == 10.0 and rows[0]["stage_rollouts"] == {"refine": 123}
    assert [r["best_distance_m"] for r in rows[0]["refine_runs"]] == [0.064, 0.088]
    assert abs(rows[0]["template_lab_cm"] - 6.6) < 1e-9 and rows[2]["template_sim_cm"] is None
    s = bench.summarize(rows)
    assert s["failed"] == [2] and s["default_subject_wall_s"] == 396.0
    assert s["median_wall_s"] == 298.0 and s["max_wall_s"] == 396.0  # over the subjects that ran
    assert abs(s["mean_template_sim_cm"] - 2.25) < 1e-9 and abs(s["max_template_lab_cm"] - 8.0) < 1e-9
    assert (s["refine_runs_reaching_0.1_m"], s["refine_runs"]) == (2, 3)
    assert "subject" in bench._table(rows)


def test_a_timed_complete_run_is_not_run_again_and_an_untimed_one_is_set_aside(tmp_path, script, monkeypatch):
    bench = script("bench_learn")
    calls = []

    def fake_run(cmd, **kwargs):
        calls.append(cmd)
        _fake_run(tmp_path / "learn_s4", 1.0, [(10, 0.5)], 0.1, 0.1)

        class Done:
            returncode = 0
        return Done()

    monkeypatch.setattr(bench.subprocess, "run", fake_run)
    (tmp_path / "learn_s4").mkdir()  # a folder left by someone else: not timed by the benchmark
    (tmp_path / "learn_s4" / "note.txt").write_text("kept")
    first = bench._run_subject(4, tmp_path, ["templates.episodes=5"], workers=1)
    assert len(calls) == 1 and calls[0][-2:] == ["--set", "templates.episodes=5"] and "demonstrations.subjects=[4]" in calls[0]
    assert first["returncode"] == 0 and (tmp_path / "learn_s4.time.json").is_file()
    aside = [p for p in tmp_path.iterdir() if p.name.startswith("learn_s4.untimed.")]
    assert len(aside) == 1 and (aside[0] / "note.txt").read_text() == "kept"  # never deleted
    again = bench._run_subject(4, tmp_path, ["templates.episodes=5"], workers=1)
    assert len(calls) == 1 and again == first  # resumed: the measured times, not a second run


def test_wall_times_in_reference_rollouts_compare_between_machines(script):
    bench = script("bench_learn")
    summary = {"default_subject_wall_s": 180.0, "median_wall_s": 150.0, "targets": {"default_wall_s": 240.0}}
    reference = {"before": {"ms_per_rollout": 5.0}, "after": {"ms_per_rollout": 7.0}}
    ref = bench._in_reference(summary, reference)
    assert ref["ms_per_rollout"] == 6.0  # the mean of the two references
    assert abs(ref["default_wall_rollouts"] - 30000.0) < 1e-6 and abs(ref["median_wall_rollouts"] - 25000.0) < 1e-6
    assert abs(ref["target_default_wall_rollouts"] - 40000.0) < 1e-6
    none = bench._in_reference({"default_subject_wall_s": None, "median_wall_s": None, "targets": {"default_wall_s": 240.0}}, reference)
    assert none["default_wall_rollouts"] is None


def test_the_reference_rollout_times_the_default_throw_on_this_machine():
    from besdrake.tasks.throwing.bench import cpu_model, reference_rollout_ms

    ref = reference_rollout_ms(n=3, reps=1)
    assert ref["throws"] == 3 and 0.0 < ref["ms_per_rollout"] < 1000.0 and 0.0 < ref["cpu_ms_per_rollout"] < 1000.0
    assert ref["cpu_model"] == cpu_model() and isinstance(ref["cpu_model"], str)
