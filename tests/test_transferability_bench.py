"""scripts/bench_transferability.py: the per-subject routine (refinement -> Transferability Approach in the lab),
its record and its resume after a kill. Slow (imitation of 8 throws, a small refinement and search)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

@pytest.mark.slow
def test_run_subject_records_and_resumes_after_a_kill(tmp_path, monkeypatch, script):
    from besdrake.commands.refine import collect_imitated
    from besdrake.tasks.throwing.lab import VirtualLab

    bench = script("bench_transferability")
    imitated = tmp_path / "imitated"
    # one experiment (8 throws) of subject 0, put where the benchmark caches a subject's imitated throws
    (imitated / "imit_s0").mkdir(parents=True)
    files = collect_imitated(["synthetic:0:0"], tmp_path / "imitation")
    assert files
    for f in files:
        shutil.copy(f, imitated / "imit_s0" / f.name)
    kwargs = dict(refine_episodes=20, population=4, max_transfers=3, lab_seed=1000, tag="ta_test",
                  ta_options={"transfer_choice": "predicted"}, refine_runs=2)

    calls = {"n": 0}
    real_execute = VirtualLab.execute

    def dying_execute(self, plan, trial=None):
        if calls["n"] == 2:
            raise KeyboardInterrupt  # the benchmark is killed during its third lab trial
        calls["n"] += 1
        return real_execute(self, plan, trial=trial)

    out = tmp_path / "s0"
    monkeypatch.setattr(VirtualLab, "execute", dying_execute)
    with pytest.raises(KeyboardInterrupt):
        bench.run_subject(0, "nominal", out, imitated, **kwargs)
    assert not (out / "ta_test" / "result.json").exists()
    refinement = json.loads((out / "refine_r20_full" / "refinement.json").read_text())
    assert refinement["episodes"] == 20 and refinement["n_imitated_throws"] == len(files)
    assert refinement["whole_budget"]  # the budget is spent on the closest throw, not stopped at the first success
    # a second run (the next seed) only when the first did not reach the goal
    second = out / "refine_r20_full_seed1" / "refinement.json"
    assert second.is_file() != refinement["success"]
    runs = [refinement] + ([json.loads(second.read_text())] if second.is_file() else [])
    assert [r["seed"] for r in runs] == list(range(len(runs)))

    monkeypatch.setattr(VirtualLab, "execute", real_execute)
    rec = bench.run_subject(0, "nominal", out, imitated, **kwargs)
    # the refinement was not redone, the two logged trials were not thrown again
    assert json.loads((out / "refine_r20_full" / "refinement.json").read_text()) == refinement
    assert rec["refinement"]["run_distances_m"] == [r["sim_distance_m"] for r in runs]
    assert rec["refinement"]["sim_distance_m"] == min(r["sim_distance_m"] for r in runs)  # the search starts from the closest
    from besdrake.transfer.log import LabLog

    assert len(LabLog.open(out / "ta_test" / "lab_log")) == rec["lab_trials"] == len(rec["trial_kinds"])
    assert 1 <= rec["transfers"] <= 3 and rec["transfers"] == rec["trial_kinds"].count("transfer")
    if rec["success"]:
        assert rec["transfers_to_success"] <= 3 and len(rec["successful_plan_lab_distances_m"]) == 3
        assert all(d < 0.1 for d in rec["successful_plan_lab_distances_m"])
    else:
        assert rec["transfers_to_success_text"] == "not within 3" and rec["transfers"] == 3
    assert len(rec["lab_target_distances_m"]) == len(rec["disparities_m"]) == rec["lab_trials"]

    # finished: read back, nothing simulated
    monkeypatch.setattr(VirtualLab, "execute", lambda *a, **k: pytest.fail("a finished subject threw again"))
    assert bench.run_subject(0, "nominal", out, imitated, **kwargs) == json.loads(json.dumps(rec))
    summary = bench.summarise([rec], 3)
    assert summary["subjects"] == 1 and summary["target_met"] == (rec["success"] and rec["transfers_to_success"] <= 3)


def test_three_of_three_probability_matches_the_closed_form_and_falls_with_the_offset(script):
    bench = script("bench_transferability")
    sd = 0.05
    p_hit = 1.0 - np.exp(-0.1**2 / (2 * sd**2))  # Rayleigh radius of a plan centred on the target
    assert bench.three_of_three_probability(sd, 0.0) == pytest.approx(p_hit**3, rel=1e-6)
    rng = np.random.default_rng(0)
    hits = np.linalg.norm(rng.normal([0.06, 0.0], sd, size=(200_000, 2)), axis=1) < 0.1
    assert bench.three_of_three_probability(sd, 0.06, repetitions=1) == pytest.approx(hits.mean(), abs=0.005)
    assert bench.three_of_three_probability(sd, 0.06) < bench.three_of_three_probability(sd, 0.02) < bench.three_of_three_probability(sd, 0.0)
