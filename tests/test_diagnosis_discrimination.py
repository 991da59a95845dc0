"""Sequential design for model discrimination: the follow-up throws separate a first log's leading causes.

The greedy choice on made-up separations (it serves the rival still close before the one already behind; missing
predictions count as no separation), the leading causes of a ranking, and a follow-up on real rollouts for a
stand-in first diagnosis: its size, repeats and limits, a rival the simulation cannot tell from the leader gets no
separation, and a rival it can gets more than from the task's random design. The CLI writes the follow-up of a
logged first experiment and refuses contradictory requests.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from besdrake.diagnosis import discrimination as dd
from besdrake.robot import load_robot
from besdrake.sim.scenario import load_scenario
from besdrake.transfer.measurement import plan_hash

COMPI = load_robot("compi")


def _cause(effects: dict, chi2: float, delta_bic: float = 0.0):
    params = [{"effect": e, "parameter": k, "value": v} for e, vals in effects.items() for k, v in vals.items()]
    return SimpleNamespace(effects=tuple(effects), parameters=params, chi2=chi2, delta_bic=delta_bic)


def test_the_greedy_choice_serves_the_close_rival_first():
    # Plan 0 separates rival A by 50 chi2, plan 1 rival B by 10; A is already 100 chi2 behind, B level with the leader.
    sep = np.array([[50.0, 0.0], [0.0, 10.0], [1.0, 1.0]])
    assert dd.greedy_discriminating(sep, np.array([100.0, 0.0]), 1) == [1]
    assert dd.greedy_discriminating(sep, np.array([0.0, 0.0]), 1) == [0]
    assert dd.greedy_discriminating(sep, np.zeros(2), 5) == [0, 1, 2]  # no more than the pool


def test_separations_are_squared_distances_from_the_leader_and_nan_counts_as_none():
    f = np.array([[[0.0, 0.0], [1.0, 1.0]], [[3.0, 4.0], [np.nan, 1.0]], [[0.0, 0.0], [1.0, 1.0]]])  # (causes, plans, F)
    np.testing.assert_allclose(dd.separations(f), [[25.0, 0.0], [0.0, 0.0]])


def test_leading_causes_put_the_named_cause_first_and_skip_its_own_effects():
    named = _cause({"ball": {"radius": 0.03}}, 10.0, 1.0)
    ranked = [_cause({"base_offset": {"x": 0.01}}, 9.0, 0.0), named, _cause({"ball": {"radius": 0.031}}, 11.0, 2.0),
              _cause({}, 40.0, 30.0), _cause({"air_drag": {"cd": 0.6}}, 12.0, 3.0)]
    d = SimpleNamespace(best=named, causes=ranked)
    lead = dd.leading_causes(d, 2)
    assert lead[0] is named and [c.effects for c in lead[1:]] == [("base_offset",), ("air_drag",)]
    assert dd.cause_effects(named) == {"ball": {"radius": 0.03}}


@pytest.fixture
def first_diagnosis():
    """A stand-in first diagnosis: nominal named, a base shifted 3 cm sideways (which every throw shows) and a
    drag coefficient at its nominal value (which none can) as rivals, the touchdown measured."""
    return SimpleNamespace(scenario=load_scenario("nominal"), best=_cause({}, 20.0),
                           causes=[_cause({}, 20.0), _cause({"base_offset": {"y": 0.03}}, 21.0, 1.0), _cause({"ball_placement": {"x": 0.0}}, 22.0, 2.0)],
                           groups_measured=["touchdown"])


def test_a_follow_up_separates_what_the_simulation_can_and_keeps_its_request(first_diagnosis, monkeypatch):
    from besdrake.sim.executors import make_executor
    from besdrake.tasks.throwing.diagnosis.design import plan_limits_exceeded

    monkeypatch.setattr(dd, "POOL_DESIGNS", 2)
    with make_executor("serial", scenario="nominal", limits="flag") as ex:
        d = dd.discriminating_plans(first_diagnosis, 6, 2, ex, seed=3, design_options={"probes": 0, "sideways": 2})
    hashes = [plan_hash(p) for p in d.plans]
    assert len(d.plans) == 6 and len(set(hashes)) == 4
    assert not any(plan_limits_exceeded(p, COMPI.limits) for p in d.plans)
    assert d.leader == "none" and d.rivals == ["base_offset", "ball_placement"]
    assert d.separation["ball_placement"] == pytest.approx(0.0, abs=1e-9)  # the same model: nothing separates it
    assert d.separation["base_offset"] > d.reference_separation["base_offset"] > 0.0


def test_a_request_without_rivals_or_with_too_many_repeats_is_a_value_error(first_diagnosis):
    alone = SimpleNamespace(**{**vars(first_diagnosis), "causes": [first_diagnosis.best]})
    with pytest.raises(ValueError, match="no rival"):
        dd.discriminating_plans(alone, 6, 2, executor=None)
    with pytest.raises(ValueError, match="repeats"):
        dd.discriminating_plans(first_diagnosis, 4, 3, executor=None)


def test_cli_writes_the_follow_up_of_a_logged_first_experiment(first_diagnosis, monkeypatch, tmp_path, capsys):
    import besdrake.diagnosis as diagnosis
    from besdrake.cli import main
    from besdrake.commands.lab_run import load_plans
    from tests.test_lab_cli import write_lab

    monkeypatch.setattr(dd, "POOL_DESIGNS", 1)
    lab = write_lab(tmp_path, {"base_offset": {"y": 0.03}})
    assert main(["diagnose", "--design", str(tmp_path / "first"), "--throws", "6", "--repeats", "2", "--probes", "0", "--sideways", "0"]) == 0
    assert main(["lab", "run", "--lab", str(lab), "--plans", str(tmp_path / "first"), "--out", str(tmp_path / "log"), "--quiet"]) == 0
    seen = []

    def first(measurements, **kw):  # the first log's diagnosis is the stand-in (its fit is tested elsewhere)
        seen.append(len(measurements))
        return SimpleNamespace(**vars(first_diagnosis), verdict="stand-in verdict")

    monkeypatch.setattr(diagnosis, "diagnose", first)
    capsys.readouterr()
    args = ["diagnose", "--design", str(tmp_path / "next"), "--after", str(tmp_path / "log"), "--throws", "4", "--repeats", "1",
            "--probes", "0", "--sideways", "1"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert seen == [6] and "follow-up to tell none from base_offset, ball_placement" in out
    assert len(load_plans(tmp_path / "next")) == 4
    # the follow-up thrown, both logs are one log to the diagnosis: trials numbered on, the files untouched
    from besdrake.commands.diagnose import _read_logs
    from besdrake.transfer.log import read_log

    assert main(["lab", "run", "--lab", str(lab), "--plans", str(tmp_path / "next"), "--out", str(tmp_path / "log2"), "--quiet"]) == 0
    both = _read_logs([tmp_path / "log", tmp_path / "log2"])
    assert [m.trial for m in both] == list(range(10)) and [m.trial for m in read_log(tmp_path / "log2")] == list(range(4))
    assert main(["diagnose", "--design", str(tmp_path / "x"), "--after", str(tmp_path / "log"), "--optimal"]) == 2
    assert main(["diagnose", "--after", str(tmp_path / "log")]) == 2
    assert main(["diagnose", "--design", str(tmp_path / "y"), "--after", str(tmp_path / "nolog")]) == 2
    assert capsys.readouterr().err.count("besdrake: error:") == 3


def test_an_informative_follow_up_adds_information_on_the_leading_causes_parameters(first_diagnosis, monkeypatch):
    from besdrake.sim.executors import make_executor

    monkeypatch.setattr(dd, "POOL_DESIGNS", 2)
    logged = [p for p in _first_plans() for _ in range(1)]
    with make_executor("serial", scenario="nominal", limits="flag") as ex:
        d = dd.informative_plans(first_diagnosis, logged, 6, 2, ex, seed=3, design_options={"probes": 0, "sideways": 2})
    assert len(d.plans) == 6 and len({plan_hash(p) for p in d.plans}) == 4
    assert sorted(d.gain) == ["ball_placement.x", "ball_placement.y"] + [f"base_offset.{k}" for k in ("pitch", "roll", "x", "y", "yaw", "z")]
    assert np.median(list(d.gain.values())) > 1.0, d.gain


def _first_plans():
    from besdrake.diagnosis import diagnosis_plans

    return diagnosis_plans(6, 2, seed=1, limits=COMPI.limits)


def test_a_pick_and_place_follow_up_goes_through_the_task_interface(monkeypatch):
    from besdrake.sim.executors import make_executor

    monkeypatch.setattr(dd, "POOL_DESIGNS", 1)
    scen = load_scenario("pick_and_place")
    first = SimpleNamespace(scenario=scen, best=_cause({"box_pose_offset": {"x": 0.02, "y": 0.0, "yaw": 0.0}}, 30.0),
                            causes=[_cause({"pad_friction": {"scale": 0.5}}, 31.0, 1.0)], groups_measured=["box", "box_yaw", "grip"])
    first.causes.insert(0, first.best)
    from besdrake.diagnosis.trials import model_for

    logged = model_for(scen).design_experiments(2, 0, seed=0, limits=scen.robot.limits, scenario="pick_and_place")
    with make_executor("serial", scenario=scen, limits="flag") as ex:
        d = dd.informative_plans(first, logged, 2, 1, ex, seed=2, design_options={"scenario": "pick_and_place"})
    assert len(d.plans) == 2 and len({plan_hash(p) for p in d.plans}) == 1
    assert d.leader == "box_pose_offset" and d.rivals == ["pad_friction"]
    assert set(d.gain) == {"box_pose_offset.x", "box_pose_offset.y", "box_pose_offset.yaw", "pad_friction.scale"}
