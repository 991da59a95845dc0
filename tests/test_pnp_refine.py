"""Pick-and-place from a demonstration to a refined grasp: path IK, retiming, the grip's closing line, the CMA-ES
refinement (resumable) and ``besdrake learn --task pick_and_place``."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from besdrake.embodiment.kinematics import welded_plant
from besdrake.embodiment.path_ik import PathIK
from besdrake.embodiment.scaling import local_retime, toppra_retime
from besdrake.plan import MotionPlan
from besdrake.robot import load_robot
from besdrake.tasks.pick_and_place.learn import DATA_DIR

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def iiwa():
    robot = load_robot("iiwa14")
    return robot, welded_plant(robot)


def _line(model, q0, shift, n=60):
    X = model.tcp_pose(q0)
    t = np.linspace(0.0, 1.0, n)
    p = X.translation() + np.outer(t, shift)
    return t, p, np.repeat(X.rotation().matrix()[None], n, axis=0)


def test_path_ik_follows_a_reachable_line_continuously(iiwa):
    robot, model = iiwa
    t, p, R = _line(model, robot.home, [0.1, -0.1, 0.05])
    ik = PathIK(model).follow(t, p, R, robot.home)
    assert ik.reachable.all() and ik.position_residual.max() < 0.002
    assert np.abs(np.diff(ik.q, axis=0)).max() < 0.1  # no jump between IK branches
    lim = robot.position_limits
    assert np.all(ik.q >= lim[:, 0]) and np.all(ik.q <= lim[:, 1])


def test_path_ik_lags_out_of_reach_without_racing(iiwa):
    robot, model = iiwa
    t, p, R = _line(model, robot.home, [2.0, 0.0, 0.0])  # 2 m out: beyond the arm's reach
    ik = PathIK(model).follow(t, p, R, robot.home)
    assert not ik.reachable[-1] and ik.position_residual[-1] > 0.5
    assert np.isfinite(ik.q).all()
    lim = robot.position_limits
    assert np.all(ik.q >= lim[:, 0]) and np.all(ik.q <= lim[:, 1])


def test_retiming_keeps_the_limits(iiwa):
    robot, model = iiwa
    t, p, R = _line(model, robot.home, [0.2, -0.3, 0.1])
    q = PathIK(model).follow(t * 0.2, p, R, robot.home).q  # 0.2 s for 38 cm: far too fast for the arm
    for t_new, q_new in [toppra_retime(t * 0.2, q, robot.limits, model, safety=0.8)[:2],
                         (local_retime(t * 0.2, q, robot.limits, safety=0.8)[0], q)]:
        v, a = MotionPlan(t=t_new, q=q_new, joint_names=robot.joint_names).validate().peak_limit_ratios(robot.limits)
        assert t_new[-1] > 0.2 and v.max() <= 1.0  # accelerations: the planner's last stretch (next test)


def test_skill_plan_keeps_the_safety_share_of_the_limits():
    from besdrake.tasks.pick_and_place.demonstrations import extract_demonstrations
    from besdrake.tasks.pick_and_place.imitation import GraspSkill
    from besdrake.tasks.pick_and_place.rollout import PickPlaceRollout
    from besdrake.tasks.pick_and_place.skill_plan import SkillPlanner

    rollout = PickPlaceRollout("pick_and_place")
    planner = SkillPlanner.for_rollout(rollout, safety=0.8)
    demo = extract_demonstrations(DATA_DIR / "subject1_run2.tsv").demonstrations[0]
    sp = planner.plan(planner.adapt(GraspSkill.from_demonstration(demo)))
    v, a = sp.plan.peak_limit_ratios(rollout.robot.limits)
    assert v.max() <= 0.81 and a.max() <= 0.81
    assert np.allclose(sp.plan.q[0], rollout.robot.home, atol=1e-6)  # starts where the arm stands
    g = sp.plan.meta["gripper"]
    assert np.all(np.diff(g["t"]) > 0) and g["width"][0] > g["width"][2]  # opens, closes on the box, opens


def test_closing_line_is_measured_and_consistent():
    from besdrake.tasks.pick_and_place.demonstrations import extract_demonstrations

    demos = extract_demonstrations(DATA_DIR / "subject1_run2.tsv").demonstrations
    axis = demos[0].closing_axis_hand
    assert np.isfinite(axis).all() and abs(np.linalg.norm(axis) - 1) < 1e-9
    # the grip closes roughly horizontally (a box grasped by its sides): the closing line in the task frame
    from besdrake.tasks.pick_and_place.imitation import rotation_matrices

    R = rotation_matrices(demos[0].hand_orientation)
    carry = (demos[0].t >= demos[0].lift_time) & (demos[0].t <= demos[0].place_time)
    vertical = np.abs((R[carry] @ axis)[:, 2])
    assert np.median(vertical) < 0.4


def _details(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_refinement_resumes_without_simulating_again(tmp_path):
    from besdrake.tasks.pick_and_place.demonstrations import extract_demonstrations
    from besdrake.tasks.pick_and_place.imitation import GraspSkill
    from besdrake.tasks.pick_and_place.refine import RefineSettings, refine_grasp
    from besdrake.tasks.pick_and_place.rollout import PickPlaceRollout
    from besdrake.tasks.pick_and_place.skill_plan import SkillPlanner

    demo = extract_demonstrations(DATA_DIR / "subject1_run2.tsv").demonstrations[0]
    skill = SkillPlanner.for_rollout(PickPlaceRollout("pick_and_place")).adapt(GraspSkill.from_demonstration(demo))
    settings = RefineSettings(max_generations=1, popsize=2, stop_on_success=False, seed=3)
    first = refine_grasp(skill, "pick_and_place", tmp_path, settings)
    rows = _details(tmp_path / "details.csv")
    assert first.episodes == 2 and len(rows) == 3  # the imitated plan, then one generation of 2
    settings.max_generations = 2
    second = refine_grasp(skill, "pick_and_place", tmp_path, settings)
    again = _details(tmp_path / "details.csv")
    assert second.episodes == 4 and len(again) == 5 and again[:3] == rows  # nothing simulated twice
    assert json.loads((tmp_path / "result.json").read_text())["episodes"] == 4


def _learn(out: Path, *extra: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "besdrake", "learn", "--task", "pick_and_place", "--quick", "--out", str(out), "--json",
           "--set", "refine.max_generations=2", "--set", "lab_trials.per_grasp=1", "--workers", "1", *extra]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=REPO, timeout=600)


def test_learn_pick_and_place_runs_and_resumes(tmp_path):
    r = _learn(tmp_path / "run")
    assert r.returncode == 0, r.stderr[-2000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    for key in ("task", "robot", "demonstrations_used", "success_rate_sim", "success_rate_lab",
                "median_episodes_to_success", "place_error_m", "wall_s"):
        assert key in out
    assert out["task"] == "pick_and_place" and out["robot"] == "iiwa14" and out["demonstrations_used"] == 1
    # the shipped recording's grasp works in simulation (refined or as imitated), so the template stage ran
    assert out["success_rate_sim"] == 1.0 and out["template_success_rate_sim"] is not None
    assert json.loads((tmp_path / "run" / "04_template" / "template.json").read_text())["type"] == "GraspTemplate"
    replay = tmp_path / "run" / out["replays"][0]
    assert replay.is_file() and "animation" in replay.read_text() and replay.name in \
        (tmp_path / "run" / "report.md").read_text()
    assert (tmp_path / "run" / "report.md").is_file()
    again = _learn(tmp_path / "run")
    assert again.returncode == 0 and json.loads(again.stdout.strip().splitlines()[-1])["stages"]["refine"] == \
        out["stages"]["refine"]


def test_learn_pick_and_place_refuses_a_missing_source(tmp_path):
    r = _learn(tmp_path / "run", "--demonstrations", str(tmp_path / "nowhere"))
    assert r.returncode == 2 and r.stderr.strip().splitlines()[-1].startswith("besdrake: error:")
    assert "Traceback" not in r.stderr


def test_a_grasp_template_interpolates_its_corrections_and_round_trips():
    from besdrake.tasks.pick_and_place.template import GraspTemplate, context_grid

    skill = _shipped_skill()
    contexts = context_grid({"dx": [-0.03, 0.12], "dy": [-0.25, 0.25]}, 5)
    assert np.allclose(contexts[0], [0.045, 0.0]) and len(np.unique(contexts, axis=0)) == 5
    corrections = np.zeros((5, 9))
    corrections[:, 2] = 0.01 * np.arange(5)  # the approach goal raised by 0..4 cm
    t = GraspTemplate(skill).fit(contexts, corrections)
    for c, k in zip(contexts, corrections):
        assert np.allclose(t.correction(c), k, atol=2e-3)
    far = t.correction([5.0, 5.0])
    assert np.allclose(far, 0.0, atol=1e-6)  # far from every training place: no correction (the GP's zero prior)
    again = GraspTemplate.from_dict(json.loads(json.dumps(t.to_dict())))
    assert np.allclose(again.correction(contexts[3]), t.correction(contexts[3]))
    assert np.allclose(GraspTemplate(skill).correction([0.0, 0.0]), 0.0)


def test_a_skill_carried_over_to_another_box_place_keeps_its_goals_relative_to_the_box():
    from besdrake.tasks.pick_and_place.rollout import PickPlaceRollout
    from besdrake.tasks.pick_and_place.skill_plan import SkillPlanner

    rollout = PickPlaceRollout("pick_and_place")
    here = SkillPlanner.for_rollout(rollout)
    skill = here.adapt(_shipped_skill())
    skill.transport.position.goal = skill.transport.position.goal + np.array([0.01, -0.02, 0.0])  # a refined goal
    there = SkillPlanner.for_rollout(rollout, box_offset=np.array([0.05, -0.2]))
    moved = there.carry_over(skill)
    assert np.allclose(moved.approach.position.goal, skill.approach.position.goal)  # the task frame moved with the box
    # the table place is the same place in the world (the base frame: the base did not move); the transport's goal
    # keeps its offset from it (release and refinement), turned with the task frame
    assert np.allclose(there.X_base_task.multiply(moved.table_place), here.X_base_task.multiply(skill.table_place))
    offset = skill.transport.position.goal - skill.table_place
    assert np.allclose(moved.transport.position.goal - moved.table_place, offset)
    start = moved.approach.open_loop(0.01).pose[0, :3]
    home = there.X_base_task.inverse() @ there.model.tcp_pose(there.robot.home)
    assert np.allclose(start, home.translation(), atol=1e-6)  # it starts from the arm's home again


def _shipped_skill():
    from besdrake.tasks.pick_and_place.demonstrations import extract_demonstrations
    from besdrake.tasks.pick_and_place.imitation import GraspSkill

    return GraspSkill.from_demonstration(extract_demonstrations(sorted(DATA_DIR.glob("*.tsv"))[0]).demonstrations[0])


def test_a_grasp_that_fails_with_the_box_shifted_is_fragile_not_a_success():
    from besdrake.tasks.pick_and_place.refine import FRAGILE_PENALTY, GraspEpisode
    from besdrake.tasks.pick_and_place.rollout import PickPlaceRollout
    from besdrake.tasks.pick_and_place.skill_plan import SkillPlanner

    skill = SkillPlanner.for_rollout(PickPlaceRollout("pick_and_place")).adapt(_shipped_skill()).to_dict()
    x = np.zeros(9)
    nominal = GraspEpisode(skill, "pick_and_place", False)(x)
    assert nominal["success"]  # the shipped demonstration's grasp works as imitated
    shaky = GraspEpisode(skill, "pick_and_place", False, box_jitter=0.06)(x)  # 6 cm: more than the pads' margin
    k = shaky["message"].count("failed")
    assert not shaky["success"] and shaky["message"].startswith("fragile") and k >= 1
    assert shaky["reward"] == pytest.approx(nominal["reward"] - FRAGILE_PENALTY * k)
