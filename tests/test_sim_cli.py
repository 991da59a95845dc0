"""CLI: simulate, record, bench rollout (slow) and the diagram renderer."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from besdrake.cli import main
from besdrake.sim.cliutil import parse_effect_option
from besdrake.sim.effects import EffectError
from besdrake.tasks.throwing.throws import default_throw

REPO = Path(__file__).resolve().parents[1]


def test_simulate_default_throw_json(capsys):
    assert main(["simulate", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["ok"] and 1.0 < d["touchdown_m"][0] < 2.5


def test_simulate_plan_file_with_effects(tmp_path, capsys):
    path = default_throw(amplitude=0.4).save(tmp_path / "plan.json")
    assert main(["simulate", "--plan", str(path), "--json"]) == 0
    plain = json.loads(capsys.readouterr().out)
    assert main(["simulate", "--plan", str(path), "--json", "--effect", "base_offset:z=0.1", "--effect", "air_drag:cd=0.3"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["effects"]["base_offset"]["z"] == 0.1 and d["effects"]["air_drag"]["cd"] == 0.3
    assert d["touchdown_m"][0] != plain["touchdown_m"][0]
    assert main(["simulate", "--plan", str(path)]) == 0
    assert "touchdown" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv, message",
    [
        (["simulate", "--effect", "nope:x=1"], "unknown effect 'nope'"),
        (["simulate", "--effect", "air_drag:cd"], "not key=value"),
        (["simulate", "--effect", "air_drag:cd=lots"], "not a number"),
        (["simulate", "--effect", "air_drag:cd=9"], "outside its bounds"),
        (["simulate", "--scenario", "nowhere"], "scenario file not found"),
        (["simulate", "--amplitude", "4.0"], "position limits"),
        (["simulate", "--plan", "/nonexistent/plan.json"], "not found"),
        (["record", "--out", "replay.txt"], "must be an .html"),
    ],
)
def test_user_errors_exit_2_with_a_message(argv, message, capsys):
    assert main(argv) == 2
    assert message in capsys.readouterr().err


def test_corrupt_plan_file(tmp_path, capsys):
    p = tmp_path / "plan.json"
    p.write_text(json.dumps({"t": [0, 1], "q": [[0] * 6, [np.nan] * 6]}).replace("NaN", "NaN"))
    assert main(["simulate", "--plan", str(p)]) == 2
    assert "NaN" in capsys.readouterr().err


def test_parse_effect_option():
    assert parse_effect_option("base_offset:z=-0.03,yaw=0.1") == ("base_offset", {"z": -0.03, "yaw": 0.1})
    assert parse_effect_option("air_drag") == ("air_drag", {})
    with pytest.raises(EffectError):
        parse_effect_option(":z=1")


def test_list_effects(capsys):
    assert main(["simulate", "--list-effects", "--json"]) == 0
    names = [e["name"] for e in json.loads(capsys.readouterr().out)]
    assert "base_offset" in names and "scoop_friction" in names


def test_record_writes_self_contained_html(tmp_path, capsys):
    out = tmp_path / "throw.html"
    assert main(["record", "--out", str(out), "--fps", "20"]) == 0
    assert "wrote" in capsys.readouterr().out
    html = out.read_text()
    assert len(html) > 100_000 and "<html" in html.lower()
    assert "meshcat" in html.lower() and "animation" in html.lower()
    assert 'src="http' not in html and "localhost:" not in html  # scripts inlined, no server needed


def test_render_diagrams_writes_dot(tmp_path, script):
    mod = script("render_diagrams")
    written = mod.render(REPO / "besdrake" / "diagrams" / "nominal.yaml", tmp_path)
    dot = written[0].read_text()
    assert written[0].suffix == ".dot"
    assert "MultibodyPlant" in dot and "motion_plan" in dot and "state_logger" in dot


@pytest.mark.slow
def test_bench_rollout_quick_json(tmp_path, capsys):
    assert main(["bench", "rollout", "--json", "--quick", "--out", str(tmp_path)]) == 0
    d = json.loads(capsys.readouterr().out)
    for key in ("max_landing_error_m", "ms_per_rollout", "rollouts_per_s", "speedup_2_workers"):
        assert key in d and np.isfinite(d[key])
    assert d["max_landing_error_m"] <= 0.03
    assert d["landing_monotonic"] and d["backends_identical"]
    assert (tmp_path / "landing_sweep.png").stat().st_size > 10_000


def test_simulate_with_record(tmp_path, capsys):
    out = tmp_path / "runs" / "default" / "throw.html"
    assert main(["simulate", "--record", str(out)]) == 0
    text = capsys.readouterr().out
    assert "touchdown" in text and "replay" in text
    assert out.stat().st_size > 100_000
