"""``besdrake learn``: configuration, the run folder, resuming, and the stages end to end."""

from __future__ import annotations

import json

import numpy as np

import pytest
import yaml

from besdrake.cli import main
from besdrake.pipeline.config import ConfigError, load_config, parse_override
from besdrake.pipeline.run import RunError, RunFolder


from besdrake.robot import load_robot

COMPI = load_robot("compi")


def test_quick_profile_user_file_and_overrides_layer_in_order(tmp_path):
    user = tmp_path / "mine.yaml"
    user.write_text(yaml.safe_dump({"refinement": {"evaluations": 321}, "workers": 1}))
    cfg = load_config(user, quick=True, overrides=["refinement.evaluations=55", "lab=other.yaml"])
    assert cfg["refinement"]["evaluations"] == 55  # flag beats file beats profile
    assert cfg["refinement"]["plans"] == 1  # from the quick profile
    assert cfg["workers"] == 1 and cfg["lab"] == "other.yaml"
    assert load_config()["refinement"]["evaluations"] == 1000  # the packaged default
    # the smoke run's 20-episode reach refinement never reaches its goal: no 800-episode search in other throws after it
    assert load_config(quick=True)["templates"]["reach_other_evaluations"] == 0 < load_config()["templates"]["reach_other_evaluations"]


def test_unknown_keys_and_bad_overrides_are_clear_errors(tmp_path):
    with pytest.raises(ConfigError, match="refinment"):
        load_config(overrides=["refinment.evaluations=5"])
    with pytest.raises(ConfigError, match="section.key=value"):
        parse_override("workers")
    bad = tmp_path / "bad.yaml"
    bad.write_text("refinement: [1, 2")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(bad)


def test_a_run_folder_refuses_another_configuration(tmp_path):
    RunFolder(tmp_path, load_config(quick=True))
    RunFolder(tmp_path, load_config(quick=True))  # the same: a resume
    with pytest.raises(RunError, match="another configuration"):
        RunFolder(tmp_path, load_config())


def test_a_run_begun_by_an_earlier_besdrake_resumes_with_its_own_configuration(tmp_path, capsys):
    """A run folder whose config.yaml lacks only settings added since (an earlier besdrake's) resumes as it began,
    and says which settings it goes without; one that differs in a setting it has is still refused."""
    old = load_config(quick=True)
    del old["refinement"]["switch_distance"], old["templates"]["reach_robust"]
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "config.yaml").write_text(yaml.safe_dump(old, sort_keys=False))
    before = (tmp_path / "run" / "config.yaml").read_text()
    run = RunFolder(tmp_path / "run", load_config(quick=True))
    assert run.config == old and sorted(run.settings_left_out) == ["refinement.switch_distance", "templates.reach_robust"]
    assert (tmp_path / "run" / "config.yaml").read_text() == before  # the run's record is not rewritten
    with pytest.raises(RunError, match="another configuration"):
        RunFolder(tmp_path / "run", load_config(quick=True, overrides=["refinement.seed=5"]))
    assert main(["learn", "--quick", "--out", str(tmp_path / "run"), "--stage", "label"]) == 0
    assert "without the settings added since: refinement.switch_distance, templates.reach_robust" in capsys.readouterr().err
    del old["transfer"]["max_transfers"]  # a setting this version reads without a fallback: refused, clearly
    (tmp_path / "older").mkdir()
    (tmp_path / "older" / "config.yaml").write_text(yaml.safe_dump(old, sort_keys=False))
    assert main(["learn", "--quick", "--out", str(tmp_path / "older"), "--stage", "label"]) == 2
    err = capsys.readouterr().err
    assert "cannot resume" in err and "max_transfers" in err and "Traceback" not in err


def test_first_stages_run_resume_and_write_their_outputs(tmp_path, capsys):
    out = tmp_path / "run"
    args = ["learn", "--quick", "--out", str(out), "--json", "--stage", "label", "--stage", "segment", "--stage", "imitate"]
    assert main(args) == 0
    records = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert records["label"]["min_correct_share"] > 0.99
    assert records["segment"]["throws"] == 8  # every demonstrated throw of the experiment found
    assert records["imitate"]["throws"] == 2 and records["imitate"]["executable"] == 2
    assert (out / "02_segment" / "synthetic_s0_e0_segments.png").is_file()
    assert len(list((out / "03_imitate").glob("*.plan.json"))) == 2
    first = json.loads((out / "01_label" / "stage.json").read_text())["finished"]
    assert main(args) == 0  # rerun: every stage is skipped
    capsys.readouterr()
    assert json.loads((out / "01_label" / "stage.json").read_text())["finished"] == first


def test_unknown_stage_is_refused(tmp_path, capsys):
    assert main(["learn", "--quick", "--out", str(tmp_path), "--stage", "nope"]) == 2
    assert "unknown stage" in capsys.readouterr().err



@pytest.mark.parametrize("override", ["transfer.placement_sd=0.01", "transfer.transfer_choice=random", "transfer.population=many",
                                      "diagnosis.probes=9", "diagnosis.repeats=-1", "diagnosis.throws=lots",
                                      "diagnosis.sideways=99", "diagnosis.sideways=some", "refinement.stop_distance=0.5",
                                      "refinement.robust_sd=0.01", "refinement.robust_sd=lots", "refinement.robust_radius=0",
                                      "refinement.robust_frontier=lots", "refinement.robust_frontier=0", "refinement.robust_frontier=0.5",
                                      "templates.reach_target=far", "templates.reach_target=[1]", "templates.reach_evaluations=-5",
                                      "templates.reach_other_evaluations=-1", "templates.reach_other_groups=0",
                                      "templates.reach_other_groups=9", "templates.reach_other_groups=many",
                                      "templates.reach_floor_goal=-0.01", "templates.reach_floor_goal=far", "refinement.run_starts=random",
                                      "templates.slowest=0.5", "templates.slowest=fast", "templates.reach_objective=sideways",
                                      "templates.follow_through=-0.1", "templates.follow_through=late",
                                      "templates.reach_robust=sometimes", "refinement.switch_distance=0",
                                      "refinement.switch_distance=far", "refinement.turn_distance=0.5",
                                      "templates.robust_sd=-0.001", "templates.robust_sd=lots", "templates.reach_stall_beyond=-1",
                                      "templates.reach_stall_beyond=far"])
def test_a_bad_refinement_transfer_or_diagnosis_setting_is_refused_before_any_stage_runs(tmp_path, capsys, override):
    code = main(["learn", "--quick", "--set", override, "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 2 and override.split(".")[0] + ":" in err and "Traceback" not in err
    assert not (tmp_path / "run").exists()


def test_the_diagnosis_design_has_sideways_throws_within_the_robots_limits():
    """Issue 25: learn's diagnosis experiment moves joints 1, 4 and 6 too (sideways throws), within the joint limits."""
    from besdrake.pipeline.learn import learn_scenario
    from besdrake.tasks.throwing.learn import diagnosis_design

    config = load_config()
    limits = learn_scenario(config).robot.limits
    distinct = {p.meta["name"]: p for p in diagnosis_design(config) if p.meta["name"].startswith("diag_")}
    side = [p for p in distinct.values() if p.meta["generator"] == "side_throw"]
    assert len(side) == config["diagnosis"]["sideways"] == 5
    for p in side:
        travel = np.abs(p.q[-1] - p.q[0])
        assert travel[0] > 1e-3 and (travel[3] > 1e-3 or travel[5] > 1e-3) and p.check_limits(limits).ok
    planar = load_config(overrides=["diagnosis.sideways=0"])
    assert all(p.meta["generator"] != "side_throw" for p in diagnosis_design(planar))
    quick = load_config(quick=True)
    assert sum(p.meta["generator"] == "side_throw" for p in {p.meta["name"]: p for p in diagnosis_design(quick)}.values()) == 2


@pytest.mark.slow
def test_quick_run_goes_from_demonstrations_to_a_template_pool(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["learn", "--quick", "--out", str(out), "--json"]) == 0
    records = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert set(records) == {"label", "segment", "imitate", "refine", "transfer", "diagnose", "transfer_refined", "template", "pool", "report"}
    assert (out / "report.md").read_text().count("| yes |") >= 5
    assert records["pool"]["templates"] == ["throw"]
    reach = records["template"]["reach_refinement"]  # the base refined further towards the farthest context
    assert reach["target_m"] == [2.35, 0.0] and reach["episodes"] <= 20 and reach["start_distance_m"] > 0
    assert reach["kept"] == ("floor_m" in reach and reach["floor_m"][1] < reach["floor_m"][0])
    assert ("08_template/reach" in records["template"]["base"]) == reach["kept"]
    # templates.reach_robust true (default): the reach refinement scores throws near its target robustly, as the
    # refinement does; templates.robust_sd: the template's episodes are rewarded over the ball's placement scatter
    reach_problem, refine_problem = (json.loads((out / f / "run0" / "problem.json").read_text()) for f in ("08_template/reach", "04_refine"))
    assert reach_problem["robust"]["radius"] > 0 and refine_problem["robust"]["radius"] > 0
    template = json.loads((out / "08_template" / "throw.template.json").read_text())
    assert "expected over 9 setups" in template["provenance"]["reward"]
    from besdrake.search.templates import TemplatePool

    plan = TemplatePool(out / "09_pool").instantiate("throw", [1.9, 0.2])
    assert plan.check_limits(COMPI.limits).ok


def test_a_second_refinement_run_scouts_from_other_imitated_throws():
    """refinement.run_starts "diverse" (the default): run 1 starts from the fifth-best imitated throw and scouts from the
    throws ranked 5-8, not again from the four best (a stalled run's family is where its scouts settle)."""
    from types import SimpleNamespace

    from besdrake.pipeline.config import ConfigError
    from besdrake.tasks.throwing.learn.refinement import _run_starts, refinement_settings

    from besdrake.robot import load_robot
    from besdrake.search.refinement import RefinementProblem
    from besdrake.tasks.throwing.template_base import fitted_default_throw

    ranking = [(i, SimpleNamespace(reward=-0.1 * r)) for r, i in enumerate([5, 2, 7, 0, 3, 6, 1, 4])]
    ranking.append((8, SimpleNamespace(reward=float("nan"))))  # a throw that failed in simulation is never a start
    base, robot = fitted_default_throw(), load_robot("compi")
    throws = [base.copy() for _ in range(9)]
    for i, d in enumerate(throws):  # nine imitated throws, told apart by their goal velocity
        d.goal_velocity = d.goal_velocity + 0.01 * i
    problems = [RefinementProblem(robot, d) for d in throws]

    def throws_of(run) -> list[int]:  # the imitated throw of each scout's start point (its family's goal velocity)
        fams = run.problem.families
        return [int(round(fams[int(x[-1])].template.goal_velocity[0] / 0.01)) for x in run.starts]

    run = _run_starts(problems, ranking, 0)
    assert run.index == 5 and throws_of(run) == [5, 2, 7, 0]
    run = _run_starts(problems, ranking, 1)
    assert run.index == 3 and throws_of(run) == [3, 6, 1, 4]
    assert _run_starts(problems, ranking, 2).index == 5  # eight usable throws: group 2 is group 0 again
    alone = _run_starts(problems, ranking, 0, scouting=False)  # no scouts: the start throw's own problem, as before
    assert alone.index == 5 and alone.problem is problems[5] and alone.starts.shape == (4, 49)
    config = {"refinement": {"run_starts": "diverse"}}
    assert refinement_settings(config)["run_starts"] == "diverse"
    with pytest.raises(ConfigError, match="run_starts"):
        refinement_settings({"refinement": {"run_starts": "random"}})


def test_learn_refines_with_the_family_switch_where_it_scouts():
    """refinement.switch_distance (default 0.3 m): learn's runs switch throw families where the race's winner stalls
    farther; a config without the key (a run folder of before) refines as before."""
    from besdrake.tasks.throwing.learn import refinement_settings

    assert refinement_settings(load_config())["switch_distance"] == 0.3
    assert refinement_settings({"refinement": {}})["switch_distance"] is None


def test_learn_checks_every_throw_by_default_and_only_those_that_could_become_a_runs_best_where_asked():
    """refinement.robust_frontier (session 38; learn's default only in session 39: a held-out subject's template lost
    its far contexts) reaches the robust check where set; null (the default) and absent (a run folder of before): every
    throw within the radius is checked."""
    from besdrake.tasks.throwing.learn.refinement import _robust_check, refinement_settings

    on = refinement_settings(load_config(overrides=["refinement.robust_frontier=0.01"]))
    assert on["robust_frontier"] == 0.01 and _robust_check("throwing", "nominal", on).frontier == 0.01
    for cfg in (load_config(), {"refinement": {"robust_sd": 0.002}}):
        off = refinement_settings(cfg)
        assert off["robust_frontier"] is None and _robust_check("throwing", "nominal", off).frontier is None


def test_a_template_base_short_of_the_floor_goal_looks_in_other_throw_families(monkeypatch, tmp_path):
    """templates.reach_other_evaluations / reach_other_groups / reach_floor_goal: only where no base so far leaves a
    floor within the goal, one reach refinement from the imitated throws of each start group after the refinement's
    (with scouts), on its own budget, up to the first whose base's floor is within the goal, never a group past the
    throws; none where the budget is 0."""
    from besdrake.tasks.throwing.learn import template as L

    calls, floors = [], {1: 0.06, 2: 0.02, 3: 0.01}

    def fake(ctx, dmps, scenario, out, budget, settings, tag, start_group=0):
        calls.append((len(dmps), budget, start_group, out.name))
        return {"start_distance_m": 1.2, "best_distance_within_limits_m": 0.3 / start_group, "runs": [{"n_episodes": budget}],
                "best_dmp": f"group{start_group}.dmp.json"}

    def floor_of(f):
        return floors[int(f.name[5])]

    monkeypatch.setattr(L, "_reach_refinement", fake)
    monkeypatch.setattr(L, "imitated_dmps", lambda ctx: ["imitated"] * 12)  # start groups 0, 1 and 2
    ctx = _refined_ctx(runs=1)
    settings = {"other_evaluations": 600, "other_groups": 3, "floor_goal": 0.03}
    assert L._other_families(ctx, "nominal", tmp_path, settings, 0.03, floor_of) == [] and not calls  # within the goal
    assert L._other_families(ctx, "nominal", tmp_path, dict(settings, other_evaluations=0), 0.3, floor_of) == [] and not calls
    found = L._other_families(ctx, "nominal", tmp_path, settings, 0.08, floor_of)
    assert calls == [(12, 600, 1, "other"), (12, 600, 2, "other_2")]  # group 2's floor is within the goal: no third
    assert found[0] == {"start_distance_m": 1.2, "best_distance_m": 0.3, "episodes": 600, "start_group": 1,
                        "best_file": tmp_path / "other" / "group1.dmp.json", "floor_m": 0.06}
    assert [f["floor_m"] for f in found] == [0.06, 0.02] and found[1]["best_file"] == tmp_path / "other_2" / "group2.dmp.json"
    floors[2] = 0.05
    del calls[:]
    assert len(L._other_families(ctx, "nominal", tmp_path, settings, 0.08, floor_of)) == 2 and calls[-1][2] == 2  # 12 throws: no group 3
    del calls[:]
    L._other_families(_refined_ctx(runs=2), "nominal", tmp_path, dict(settings, other_groups=1), 0.08, floor_of)  # runs 0, 1: groups 0, 1
    assert calls == [(12, 600, 2, "other")]


def _refined_ctx(runs: int, run_starts: str = "diverse"):
    """A stand-in learn Context whose refinement stage ran ``runs`` CMA-ES runs."""
    from types import SimpleNamespace

    summary = {"runs": [{"dmp": f"refined{k}.dmp.json"} for k in range(runs)]}
    return SimpleNamespace(run=SimpleNamespace(done=lambda i, name: {"summary": summary}),
                           config={"refinement": {"run_starts": run_starts}})


def test_the_other_family_starts_after_the_groups_the_refinement_searched():
    from besdrake.tasks.throwing.learn import template as L

    assert [L._unsearched_group(_refined_ctx(n)) for n in (1, 2, 3)] == [1, 2, 3]
    assert L._unsearched_group(_refined_ctx(2, run_starts="same")) == 1  # every run started from the best four


def test_a_reach_refinement_that_stalls_goes_on_from_the_other_refinement_runs_throws(monkeypatch, tmp_path):
    """templates.reach_other_runs: only where the reach refinement ended beyond the goal, one more from each refinement
    run's throw of another family than the base (same budget); the base's own family and a setting of false: none."""
    from types import SimpleNamespace

    from besdrake.sim.scenario import load_scenario
    from besdrake.tasks.throwing.learn import template as L
    from besdrake.tasks.throwing.template_base import fitted_default_throw

    refine = tmp_path / "04_refine"
    refine.mkdir()
    base = fitted_default_throw()
    other = base.copy()
    other.goal_velocity = other.goal_velocity + 0.3  # imitated from another throw: another goal velocity
    same = base.copy()
    same.weights = same.weights + 1.0  # refined from the base's own throw
    for i, d in enumerate((same, other)):
        d.save(refine / f"refined{i}.dmp.json")
    base.save(tmp_path / "best.dmp.json")
    ctx = SimpleNamespace(run=SimpleNamespace(root=tmp_path), robot=lambda scenario=None: load_scenario("nominal").robot)
    assert L._other_run_throws(ctx, tmp_path / "best.dmp.json", "nominal") == [refine / "refined1.dmp.json"]

    calls = []

    def fake(ctx, dmps, scenario, out, budget, settings, tag, start_group=0):
        calls.append((dmps[0].goal_velocity.copy(), budget, out.name))
        return {"start_distance_m": 0.39, "best_distance_within_limits_m": 0.07, "runs": [{"n_episodes": 300}], "best_dmp": "refined0.dmp.json"}

    monkeypatch.setattr(L, "_reach_refinement", fake)
    settings = {"other_runs": True, "evaluations": 800}
    assert L._other_runs_reach(ctx, tmp_path / "best.dmp.json", "nominal", tmp_path / "reach", settings, 0.08) == [] and not calls
    assert L._other_runs_reach(ctx, tmp_path / "best.dmp.json", "nominal", tmp_path / "reach", settings | {"other_runs": False}, 0.35) == []
    found = L._other_runs_reach(ctx, tmp_path / "best.dmp.json", "nominal", tmp_path / "reach", settings, 0.35)
    assert len(calls) == 1 and np.allclose(calls[0][0], other.goal_velocity) and calls[0][1:] == (800, "refined1")
    assert found == [("refined1.dmp.json", {"start_distance_m": 0.39, "best_distance_m": 0.07, "episodes": 300,
                                            "best_file": tmp_path / "reach" / "refined1" / "refined0.dmp.json"})]


def test_refinement_runs_in_turn_stop_at_the_first_that_succeeds():
    from types import SimpleNamespace

    from besdrake.search.refinement.run import RefinementResult
    from besdrake.tasks.throwing.learn.refinement import _runs_in_turn

    def run(distances, robust=None):
        d = np.array(distances, dtype=float)
        r = np.full(d.size, np.nan) if robust is None else np.array(robust, dtype=float)
        ns = SimpleNamespace(distances=d, robust_distances=r, successes=d < 0.1)
        ns.reached = lambda stop_distance: RefinementResult.reached(ns, stop_distance)  # the result's own rule
        return ns

    calls = []

    def job(result):
        return lambda ex: calls.append(ex) or result

    failed, near, robustly_far = run([0.5, 0.3]), run([0.4, 0.04]), run([0.04], robust=[0.08])
    assert _runs_in_turn([job(failed), job(near), job(failed)], "ex", 0.05) == [failed, near]  # the third never runs
    assert len(calls) == 2 and calls == ["ex", "ex"]
    # a success outside the stop distance (its robust distance where checked) does not end the turn
    assert _runs_in_turn([job(robustly_far), job(near)], "ex", 0.05) == [robustly_far, near]
    # a turn distance at the goal: a run within it ends the turn though it never got within the stop distance
    assert _runs_in_turn([job(robustly_far), job(near)], "ex", 0.1) == [robustly_far]


def test_the_turn_distance_defaults_to_the_stop_distance_and_is_checked():
    from besdrake.pipeline.config import ConfigError, load_config
    from besdrake.tasks.throwing.learn import refinement_settings

    assert refinement_settings(load_config(overrides=["refinement.turn_distance=0.1"]))["turn_distance"] == 0.1
    assert refinement_settings(load_config())["turn_distance"] in (None, 0.1)
    for bad in ("0", "0.5", "far"):
        with pytest.raises(ConfigError, match="turn_distance"):
            refinement_settings(load_config(overrides=[f"refinement.turn_distance={bad}"]))

def test_the_transfer_is_seeded_with_the_refinements_best_throw_first(tmp_path):
    """The first seed is the Transferability search's template (its goal velocity): the refinement's best throw."""
    from besdrake.tasks.throwing.learn.transfer import _seed_files

    for name in ("refined0.dmp.json", "refined1.dmp.json", "refined2.dmp.json", "other.json"):
        (tmp_path / name).write_text("{}")
    assert [f.name for f in _seed_files(tmp_path, "refined1.dmp.json")] == ["refined1.dmp.json", "refined0.dmp.json", "refined2.dmp.json"]
    assert [f.name for f in _seed_files(tmp_path, None)] == ["refined0.dmp.json", "refined1.dmp.json", "refined2.dmp.json"]


def test_the_template_base_looks_in_other_families_with_the_smallest_floor_so_far(monkeypatch, tmp_path):
    """_template_base: the imitated throws' families are searched with the smallest reach floor of the bases so far
    (another refinement run's included), and the floor rule picks among every base found."""
    import contextlib
    from types import SimpleNamespace

    import besdrake.imitation as imitation
    import besdrake.search.templates as templates
    import besdrake.tasks.throwing.template_base as template_base
    from besdrake.tasks.throwing.learn import template as L

    settings = {"target": (2.35, 0.0), "evaluations": 800, "slowest": 2.0, "follow_through": 0.05, "objective": "point"}
    first = {"runs": [{"stop_reason": "stall", "n_episodes": 400}], "start_distance_m": 0.4, "best_distance_within_limits_m": 0.35,
             "best_dmp": "refined0.dmp.json"}
    monkeypatch.setattr(L, "_best_throw", lambda ctx: tmp_path / "best.dmp.json")
    monkeypatch.setattr(L, "template_reach_settings", lambda config: settings)
    monkeypatch.setattr(L, "_reach_refinement", lambda *a, **k: first)
    monkeypatch.setattr(L, "_executor", lambda ctx, scenario: contextlib.nullcontext("ex"))
    monkeypatch.setattr(imitation, "load_dmp", lambda f: str(f))
    monkeypatch.setattr(template_base, "follow_through_phase", lambda *a: None)
    floors = {"best.dmp.json": 0.12, "refined0.dmp.json": 0.08, "run1.dmp.json": 0.05, "other.dmp.json": 0.02}
    monkeypatch.setattr(templates, "reach_floor", lambda d, *a, **k: floors[d.split("/")[-1]])
    ctx = SimpleNamespace(config={}, robot=lambda scenario: None)
    seen = []

    def other_families(ctx, scenario, out, settings, floor, floor_of):
        seen.append(floor)
        f = out / "other" / "other.dmp.json"
        return [{"start_distance_m": 1.6, "best_distance_m": 0.03, "episodes": 510, "start_group": 1, "best_file": f,
                 "floor_m": floor_of(f)}]

    monkeypatch.setattr(L, "_other_families", other_families)
    run1 = {"start_distance_m": 0.3, "best_distance_m": 0.2, "episodes": 300, "best_file": tmp_path / "run1.dmp.json"}
    monkeypatch.setattr(L, "_other_runs_reach", lambda *a: [("refined1.dmp.json", run1)])
    base, record = L._template_base(ctx, "nominal", tmp_path / "reach")
    assert seen == [0.05]  # the other run's base leaves the smallest floor so far
    assert record["floor_m"] == [0.12, 0.08, 0.05, 0.02] and record["other_families"][0]["start_group"] == 1
    assert base == tmp_path / "reach" / "other" / "other.dmp.json" and record["kept_from"] == "other throws (start group 1)"
    floors["other.dmp.json"] = 0.09
    monkeypatch.setattr(L, "_other_runs_reach", lambda *a: [])
    base, record = L._template_base(ctx, "nominal", tmp_path / "reach")
    assert seen[-1] == 0.08 and base == tmp_path / "reach" / "refined0.dmp.json" and record["kept_from"] == "reach refinement"


def test_reach_refinements_from_refined_throws_also_end_by_the_far_stall_rule(monkeypatch):
    """templates.reach_stall_beyond: the reach refinements from refined throws (start group 0) end by the far stall rule
    as well as the refinement's own; the search in other throws (scouts) by the refinement's only; null: off; the
    setting is checked."""
    from besdrake.pipeline.config import ConfigError, load_config
    from besdrake.search.refinement import AnyStall, StallRule
    from besdrake.tasks.throwing.learn import template as L

    settings = L.template_reach_settings(load_config())
    far = settings["far_stall"]
    assert far == StallRule(L.REACH_FAR_STALL_EPISODES, L.REACH_FAR_STALL_TOL, L.REACH_FAR_STALL_AFTER, 0.25)
    assert L.template_reach_settings(load_config(overrides=["templates.reach_stall_beyond=null"]))["far_stall"] is None
    for bad in ("-0.1", "3", "far"):
        with pytest.raises(ConfigError, match="reach_stall_beyond"):
            L.template_reach_settings(load_config(overrides=[f"templates.reach_stall_beyond={bad}"]))
    seen = []
    monkeypatch.setattr(L, "refine_from", lambda *a, **k: seen.append(k["far_stall"]))
    L._reach_refinement(None, [], "nominal", None, 800, settings, "template reach")
    L._reach_refinement(None, [], "nominal", None, 800, settings, "template reach (other throws)", start_group=1)
    assert seen == [far, None]
    usual = StallRule()
    assert AnyStall.of(usual, far) == AnyStall((usual, far)) and AnyStall.of(usual, None) is usual
    assert AnyStall.of(None, far) is far and AnyStall.of(None, None) is None


def test_the_report_tells_where_the_template_base_came_from():
    """report.md's template section: each reach refinement (from where, start -> best, episodes), the floors and the kept
    base; nothing without a reach target."""
    from besdrake.tasks.throwing.learn.report import _reach_lines

    reach = {"target_m": [2.35, 0.0], "start_distance_m": 0.397, "best_distance_m": 0.355, "episodes": 150,
             "other_family": {"start_distance_m": 1.606, "best_distance_m": 0.030, "episodes": 510, "start_group": 1},
             "floor_m": [0.1197, 0.0829, 0.0295], "kept": True, "kept_from": "other throws"}
    text = "\n".join(_reach_lines(reach))
    assert "(2.35, 0) m" in text and "from the refined throw: 0.397 -> 0.355 m in 150 episodes" in text
    assert "start group 1: 1.606 -> 0.030 m in 510 episodes" in text
    assert "Template base kept: other throws" in text and "12.0 / 8.3 / 2.9 cm" in text
    two = {k: v for k, v in reach.items() if k != "other_family"} | {"other_families": [
        {"start_distance_m": 1.606, "best_distance_m": 0.310, "episodes": 800, "start_group": 1},
        {"start_distance_m": 1.702, "best_distance_m": 0.041, "episodes": 420, "start_group": 2}]}  # since session 46
    text = "\n".join(_reach_lines(two))
    assert "start group 1: 1.606 -> 0.310 m in 800 episodes" in text and "start group 2: 1.702 -> 0.041 m in 420 episodes" in text
    assert _reach_lines({}) == []
