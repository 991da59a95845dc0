"""``besdrake lab run``: fills a log, resumes, refuses a different run, loads --plugin, reports bad input."""

from __future__ import annotations

import json
import uuid

import numpy as np
import pytest
import yaml

from besdrake.cli import main
from besdrake.sim.effects import unregister_effect
from besdrake.tasks.throwing.throws import default_throw
from besdrake.transfer.log import LabLog, read_log


def write_lab(tmp_path, effects=None, name="cli_lab"):
    cfg = {
        "name": name,
        "scenario": "nominal",
        "seed": 0,
        "effects": effects or {},
        "noise": {"touchdown_sd": 0.05, "ball_placement_sd": 0.002, "mocap_noise_sd": 0.001},
        "record_ball_path": False,
        "record_joints": True,
    }
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def test_lab_run_fills_resumes_and_checks(tmp_path, capsys):
    lab = write_lab(tmp_path)
    plans = tmp_path / "plans.json"
    plans.write_text(json.dumps([default_throw(a).to_dict() for a in (0.3, 0.4)] + [default_throw(0.35, accel=30.0).to_dict()]))
    out = tmp_path / "log"
    args = ["lab", "run", "--lab", str(lab), "--plans", str(plans), "--seed", "5", "--out", str(out), "--quiet"]
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["trials"] == 3 and summary["executed_now"] == 3
    assert summary["flag_counts"] == {"refused_by_safety_gate": 1}
    ms = read_log(out)
    assert ms[0].joint_t is not None and ms[0].ball_t is None and ms[0].meta["plan_name"] == "plans[0]"
    assert LabLog.open(out).header["run"]["seed"] == 5
    # the same command again resumes: nothing is repeated
    assert main(args) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["executed_now"] == 0 and again["resumed_after"] == 3 and again["trials"] == 3
    # another seed into the same folder is a different run
    other = list(args)
    other[other.index("--seed") + 1] = "6"
    assert main(other) == 2
    assert "seed" in capsys.readouterr().err


def test_lab_run_plan_folder_and_plugin(tmp_path, capsys):
    name = f"cli_plugin_drag_{uuid.uuid4().hex[:8]}"
    plugin = tmp_path / "drag_plugin.py"
    plugin.write_text(
        "from besdrake.sim.effects import Effect, Param, register_effect\n"
        "@register_effect\n"
        "class Drag(Effect):\n"
        "    '''Test plugin: air drag.'''\n"
        f"    name = {name!r}\n"
        "    applied_via = 'flight'\n"
        "    params = {'cd': Param(0.0, 0.0, 1.0, '1')}\n"
        "    def apply(self, setup, values):\n"
        "        setup.drag_coefficient = values['cd']\n"
    )
    folder = tmp_path / "plans"
    folder.mkdir()
    default_throw(0.35).save(folder / "b_second.plan.json")
    default_throw(0.3).save(folder / "a_first.plan.json")
    try:
        lab = write_lab(tmp_path, effects={name: {"cd": 0.5}}, name="plugin_lab")
        # without --plugin the effect is unknown
        rc = main(["lab", "run", "--lab", str(lab), "--plans", str(folder), "--out", str(tmp_path / "x"), "--quiet"])
        assert rc == 2 and name in capsys.readouterr().err
        assert not (tmp_path / "x").exists(), "nothing is written before the configuration is valid"
        assert main(["lab", "run", "--lab", str(lab), "--plans", str(folder), "--out", str(tmp_path / "log"),
                     "--plugin", str(plugin), "--quiet"]) == 0
        ms = read_log(tmp_path / "log")
        assert [m.meta["plan_name"] for m in ms] == ["a_first", "b_second"]
    finally:
        unregister_effect(name)


def test_lab_run_reports_bad_input(tmp_path, capsys):
    lab = write_lab(tmp_path)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps([{"t": [0, 1], "q": [[0] * 6, [float("nan")] * 6]}]))
    assert main(["lab", "run", "--lab", str(lab), "--plans", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "plan 0" in capsys.readouterr().err
    assert main(["lab", "run", "--lab", str(tmp_path / "none.yaml"), "--plans", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "not found" in capsys.readouterr().err
    assert main(["lab", "run", "--lab", str(lab), "--plans", str(bad), "--out", str(tmp_path / "o"),
                 "--plugin", str(tmp_path / "missing.py")]) == 2
    assert "plugin file not found" in capsys.readouterr().err


@pytest.mark.slow
def test_sigkilled_cli_run_resumes_to_the_same_log(tmp_path):
    """A real kill (SIGKILL mid-run), then the same command: the log equals an uninterrupted run's."""
    import os
    import signal
    import subprocess
    import sys
    import time

    lab = write_lab(tmp_path)
    plans = tmp_path / "plans.json"
    plans.write_text(json.dumps([default_throw(a).to_dict() for a in np.linspace(0.25, 0.5, 10)]))

    def cmd(out):
        return [sys.executable, "-m", "besdrake", "lab", "run", "--lab", str(lab), "--plans", str(plans), "--out", str(out), "--quiet"]

    subprocess.run(cmd(tmp_path / "ref"), check=True, capture_output=True)
    proc = subprocess.Popen(cmd(tmp_path / "run"), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    csv_path = tmp_path / "run" / "trials.csv"
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        if csv_path.is_file() and len(csv_path.read_text().splitlines()) >= 4:  # header + 3 trials
            break
        time.sleep(0.01)
    assert proc.poll() is None, "the run finished before it could be killed"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    n_before = len(LabLog.open(tmp_path / "run"))
    assert 3 <= n_before < 10
    subprocess.run(cmd(tmp_path / "run"), check=True, capture_output=True)
    got, want = read_log(tmp_path / "run"), read_log(tmp_path / "ref")
    assert [m.trial for m in got] == list(range(10))
    for a, b in zip(got, want):
        assert a.plan_hash == b.plan_hash
        np.testing.assert_array_equal(a.touchdown, b.touchdown)
        np.testing.assert_array_equal(a.q_measured, b.q_measured)
