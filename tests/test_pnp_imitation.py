"""Grasp imitation and embodiment: pose IK, the grasp skill (two chained Cartesian DMPs), its plan on a robot.

Robots: COMPI (6 joints, no gripper: a stand-in arm) and ``test_gripper_arm`` (tests/gripper_arm.py: 7 joints
with the iiwa 14's link lengths and two prismatic fingers, written into a temporary folder; not the iiwa model,
which another branch builds).
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw

from besdrake.embodiment.kinematics import welded_plant
from besdrake.embodiment.pose_ik import PoseIKOptions, pose_ik_trajectory
from besdrake.robot import load_robot
from besdrake.tasks.pick_and_place.classifier import load_classifier
from besdrake.tasks.pick_and_place.demonstrations import extract_demonstrations
from besdrake.tasks.pick_and_place.grasp_plan import grasp_plan, gripper_widths, scene_task_frame, with_lead_in
from besdrake.tasks.pick_and_place.imitation import GraspImitationError, GraspSkill, grasp_point_path
from besdrake.tasks.pick_and_place.parameters import GraspParameterization
from gripper_arm import write_gripper_arm

PACKAGE = Path(__file__).resolve().parents[1] / "besdrake"
#: Where the scenes put the task frame (the box on the shelf; task x towards the table) in each robot's base
#: frame: the shelf in front and to the left of the base, the table to the right, 0.54 m lower.
X_BASE_TASK = {
    "test_gripper_arm": RigidTransform(RollPitchYaw(0, 0, -np.pi / 2), [0.7, 0.6, 0.4]),
    "compi": RigidTransform(RollPitchYaw(0, 0, -np.pi / 2), [0.75, 0.55, 0.5]),
}
#: Stated tolerances (m) of the plan's tool path against the demonstrated grasp point's path, where reachable:
#: the DMP's imitation error plus the approach's goal moved onto the box (the person's grasp point lies 1-4 cm
#: from it when the approach ends).
PATH_MEAN_TOL, PATH_MAX_TOL = 0.025, 0.05
#: Tool against the IK target where reachable: the 2 mm per-axis position tolerance.
IK_TOL = 0.0035
#: IK every 80 ms here (the default 40 ms in scripts/bench_pnp_imitation.py): half the test's time.
IK_DT = 0.08


@pytest.fixture(scope="module")
def demos(shared_data):
    clf = load_classifier()
    out = []
    for f in sorted((shared_data / "pick_and_place").glob("*.tsv")):
        out += extract_demonstrations(f, classifier=clf).demonstrations
    return out


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    robot = load_robot(write_gripper_arm(tmp_path_factory.mktemp("arm")))
    return robot, welded_plant(robot)


@pytest.fixture(scope="module")
def compi():
    robot = load_robot("compi")
    return robot, welded_plant(robot)


@pytest.fixture(scope="module")
def arm_plans(demos, arm):
    robot, model = arm
    return [grasp_plan(d, robot, X_BASE_TASK[robot.name], model=model, ik_dt=IK_DT) for d in demos]


# -------------------------------------------------------------------------------- pose IK
def _fk_path(model, q0, q1, n=41):
    s = 0.5 - 0.5 * np.cos(np.linspace(0, np.pi, n))
    q = q0 + s[:, None] * (q1 - q0)
    X = [model.tcp_pose(qi) for qi in q]
    return np.linspace(0, 2, n), np.array([x.translation() for x in X]), np.array([x.rotation().matrix() for x in X])


@pytest.mark.parametrize("tolerance", [None, 0.01])
def test_pose_ik_reaches_compis_own_poses(compi, tolerance):
    _, model = compi
    t, p, R = _fk_path(model, np.array([0.3, 0.5, 0.8, 0.2, 0.7, -0.4]), np.array([-0.6, 0.2, 1.2, -0.5, 0.3, 0.6]))
    ik = pose_ik_trajectory(model, t, p, R, np.array([0.5, 0.7, 1.0, 0.4, 0.9, -0.2]),
                            options=PoseIKOptions(orientation_tolerance=tolerance))
    assert ik.reachable.all()
    assert ik.position_residual.max() < 1e-3 and ik.angle_residual.max() < np.radians(0.5)
    assert ik.jumps() == [] and ik.q.shape == (len(t), 6)


def test_pose_ik_moves_only_the_arm_of_a_robot_with_a_gripper(arm):
    robot, model = arm
    assert model.plant.num_positions() == 9 and list(model.gripper_indices) == [7, 8]
    t, p, R = _fk_path(model, robot.home, robot.home + np.array([0.4, -0.3, 0.2, 0.3, -0.4, 0.2, 0.5]), n=21)
    ik = pose_ik_trajectory(model, t, p, R, robot.home, gripper=np.array([0.01, 0.01]),
                            options=PoseIKOptions(orientation_tolerance=0.01))
    assert ik.q.shape == (21, 7) and ik.reachable.all()
    assert ik.position_residual.max() < 1e-3 and ik.angle_residual.max() < 0.01
    assert np.all(robot.limits.within(ik.q, margin=0.049))


def test_pose_ik_with_a_finger_that_mimics_the_gripper_joint(tmp_path):
    robot = load_robot(write_gripper_arm(tmp_path, mimic=True))
    model = welded_plant(robot)
    assert model.plant.num_positions() == 9 and list(model.gripper_indices) == [7]
    t, p, R = _fk_path(model, robot.home, robot.home + 0.2, n=5)
    ik = pose_ik_trajectory(model, t, p, R, robot.home)
    assert ik.reachable.all() and ik.position_residual.max() < 1e-3


def test_pose_ik_reports_an_unreachable_pose_with_its_residual(compi):
    robot, model = compi
    t, p, R = _fk_path(model, robot.home + 0.3, robot.home + 0.5, n=3)
    p[1] = [3.0, 0.0, 0.5]  # 3 m away: beyond COMPI's reach
    ik = pose_ik_trajectory(model, t, p, R, robot.home + 0.3)
    assert list(ik.reachable) == [True, False, True]
    report = ik.unreachable_report()
    assert [r["index"] for r in report] == [1] and report[0]["position_residual_m"] > 1.0


def test_pose_ik_rejects_bad_targets(compi):
    _, model = compi
    with pytest.raises(ValueError, match="finite"):
        pose_ik_trajectory(model, [0.0], [[np.nan, 0, 0]], [[1.0, 0, 0, 0]], np.zeros(6))
    with pytest.raises(ValueError, match="orientations"):
        pose_ik_trajectory(model, [0.0], [[0.3, 0, 0.5]], [[1.0, 0, 0]], np.zeros(6))


def test_stage_folders_name_no_pick_and_place_objects():
    stages = ("mocap", "segmentation", "imitation", "embodiment", "sim", "search", "transfer", "diagnosis", "pipeline")
    hits = [f"{p.relative_to(PACKAGE)}:{i}" for s in stages for p in sorted((PACKAGE / s).rglob("*.py"))
            for i, line in enumerate(p.read_text().splitlines(), 1) if re.search(r"shelf|grasp", line, re.IGNORECASE)]
    assert hits == []
    assert not re.search(r"\bbox", (PACKAGE / "embodiment" / "pose_ik.py").read_text(), re.IGNORECASE)


# -------------------------------------------------------------------------------- the skill
def test_the_skill_chains_its_segments_and_reproduces_the_demonstration(demos):
    for d in demos:
        skill = GraspSkill.from_demonstration(d)
        path, _ = grasp_point_path(d)
        traj = skill.rollout(1.0 / 120)
        err = np.linalg.norm(np.array([np.interp(d.t, traj.t, traj.pose[:, j]) for j in range(3)]).T - path, axis=1)
        assert err.mean() < 0.015 and err.max() < 0.05, (d.source, err.mean(), err.max())
        k = int(round(skill.approach.execution_time * 120))  # the border sample: velocity continuous there
        v = traj.velocity[:, :3]
        assert np.linalg.norm(v[k + 1] - v[k]) < 0.05, d.source
        assert skill.close_time == pytest.approx(skill.approach.execution_time - 0.2) and skill.open_time >= skill.duration - 0.5


def test_the_skill_goals_are_the_scene_places(demos):
    skill = GraspSkill.from_demonstration(demos[0])
    table = skill.table_place + np.array([-0.3, 0.1, 0.05])
    moved = skill.adapted(table_place=table).rollout(0.01)
    assert np.allclose(moved.pose[-1, :3], table + skill.release_offset, atol=0.01)
    a_end = int(round(skill.approach.execution_time / 0.01))
    assert np.linalg.norm(moved.pose[a_end, :3]) < 0.005  # the approach ends on the box (task origin)
    again = GraspSkill.from_dict(skill.to_dict()).rollout(0.01)
    assert np.allclose(again.pose, skill.rollout(0.01).pose)


def test_an_approach_reaching_from_a_robot_start_keeps_the_last_stretch(demos):
    """The reach from the resting hand is cropped at the new start's distance; the path starts there at rest and
    ends as demonstrated; the gripper times move with the crop."""
    for d in demos[:4]:
        skill = GraspSkill.from_demonstration(d)
        goal = skill.approach.position.goal
        start = goal + np.array([0.5, 0.15, 0.12])
        new = skill.reaching_from(start)
        old, a = skill.approach.open_loop(0.01), new.approach.open_loop(0.01)
        assert np.allclose(a.pose[0, :3], start) and not new.approach.position.start_velocity.any()
        assert np.linalg.norm(a.pose[-1, :3] - goal) < 0.01
        shift = skill.approach.execution_time - new.approach.execution_time
        farther = np.linalg.norm(old.pose[0, :3] - goal) > np.linalg.norm(start - goal)
        assert (0.0 < shift < skill.approach.execution_time) if farther else shift == 0.0
        assert new.close_time == pytest.approx(skill.close_time - shift, abs=0.02)
        assert new.open_time == pytest.approx(skill.open_time - shift, abs=0.02)
        # the last 5 cm towards the box: within 1 cm of the demonstrated path
        near = np.linalg.norm(a.pose[:, :3] - goal, axis=1) < 0.05
        gap = [np.min(np.linalg.norm(old.pose[:, :3] - p, axis=1)) for p in a.pose[near, :3]]
        assert max(gap) < 0.01, (d.source, max(gap))
        # the path never strays far from the segment between the new start and the goal
        assert np.linalg.norm(a.pose[:, :3] - goal, axis=1).max() < 1.3 * np.linalg.norm(start - goal), d.source


def test_a_bad_demonstration_is_a_clear_error(demos):
    d = demos[0]
    with pytest.raises(GraspImitationError, match="hand_position contains NaN"):
        bad = dataclasses.replace(d, hand_position=d.hand_position.copy())
        bad.hand_position[5, 1] = np.nan
        GraspSkill.from_demonstration(bad)
    with pytest.raises(GraspImitationError, match="at least 10 samples"):
        GraspSkill.from_demonstration(dataclasses.replace(d, border_index=4))
    n = 12
    short = dataclasses.replace(d, t=d.t[:n], hand_position=d.hand_position[:n], hand_orientation=d.hand_orientation[:n],
                                box_position=d.box_position[:n], aperture=d.aperture[:n])
    with pytest.raises(GraspImitationError, match="samples"):
        grasp_plan(short, "compi", X_BASE_TASK["compi"])


def test_parameter_vector_round_trip_and_bounds(demos):
    skill = GraspSkill.from_demonstration(demos[0])
    param = GraspParameterization(skill)
    theta = param.to_vector()
    assert theta.shape == (param.n_params,) == (9 + 2 * 3 * 20,)
    assert np.allclose(param.to_vector(param.from_vector(theta)), theta)
    theta0, scale, bounds = param.scaling()
    assert np.all(bounds[:, 0] < theta0) and np.all(theta0 < bounds[:, 1]) and np.all(scale > 0)
    moved = theta.copy()
    moved[3] *= 1.5  # a slower approach: the close time moves with it, the open time keeps its delay
    s = param.from_vector(moved)
    assert s.approach.execution_time - s.close_time == pytest.approx(skill.approach.execution_time - skill.close_time)
    assert s.open_time - s.duration == pytest.approx(skill.open_time - skill.duration)
    assert GraspParameterization(skill, weights=False).n_params == 9
    with pytest.raises(GraspImitationError, match="approach.tau"):
        param.from_vector(np.where(np.arange(len(theta)) == 3, -1.0, theta))


# -------------------------------------------------------------------------------- plans on robots
def _tool_path(model, q):
    return np.array([model.tcp_pose(qi).translation() for qi in q])


def test_every_demonstration_gives_a_plan_that_reproduces_its_path(demos, arm, arm_plans):
    robot, model = arm
    assert {Path(d.source).stem.split("_")[0] for d in demos} == {"subject1", "subject2"}
    X = X_BASE_TASK[robot.name]
    for d, gp in zip(demos, arm_plans):
        ok = gp.ik.reachable
        assert ok.mean() > 0.8, (d.source, gp.summary())
        tool = _tool_path(model, gp.ik.q)
        assert np.linalg.norm(tool - gp.target_position, axis=1)[ok].max() < IK_TOL
        path, _ = grasp_point_path(d)
        demo = np.array([np.interp(gp.ik.t, d.t, c) for c in (path @ X.rotation().matrix().T + X.translation()).T]).T
        err = np.linalg.norm(tool - demo, axis=1)[ok]
        assert err.mean() < PATH_MEAN_TOL and err.max() < PATH_MAX_TOL, (d.source, err.mean(), err.max())
        assert gp.plan.check_limits(robot.limits).ok, (d.source, gp.plan.check_limits(robot.limits).violations())
        assert gp.plan.joint_names == robot.joint_names and gp.scaling.factor >= 1.0


def test_the_gripper_closes_at_the_box_before_the_lift(arm, arm_plans):
    robot, model = arm
    w_open, w_closed = gripper_widths(robot)
    assert (w_open, w_closed) == (pytest.approx(0.11), 0.0)
    for gp in arm_plans:
        g = gp.plan.meta["gripper"]
        t, w = np.array(g["t"]), np.array(g["width"])
        assert w[0] == w_open and w_closed in w and w[-1] == w_open
        close_start, closed = t[np.argmax(w < w_open) - 1], t[np.argmax(w == w_closed)]
        grasp = gp.X_base_task.translation()  # the tool's goal at the approach's end: on the box
        times = np.linspace(0, gp.plan.duration, 2000)
        dist = np.linalg.norm(_tool_path(model, gp.plan.sample(times)) - grasp, axis=1)
        lift = times[(times > closed) & (dist > 0.01)][0]  # the tool leaves the box's place, carrying it
        d_start, d_closed = np.interp([close_start, closed], times, dist)
        print(Path(gp.skill.source).stem, f"closing starts {d_start * 1000:.0f} mm from the box, closed at "
              f"{d_closed * 1000:.1f} mm, {lift - closed:.2f} s before the lift")
        assert d_closed < 0.01 and d_start < 0.06 and lift > closed, (gp.skill.source, d_start, d_closed, closed, lift)


def test_the_same_demonstration_on_two_robots(demos, compi, arm_plans):
    robot, model = compi
    gp = grasp_plan(demos[0], robot, X_BASE_TASK["compi"], model=model)
    assert gp.plan.joint_names == robot.joint_names != arm_plans[0].plan.joint_names
    assert "gripper" not in gp.plan.meta and any("no gripper" in n for n in gp.notes)
    assert gp.plan.check_limits(robot.limits).ok
    ok = gp.ik.reachable
    assert ok.mean() > 0.5  # COMPI misses some of the human's wrist orientations (reported per pose)
    tool = _tool_path(model, gp.ik.q)
    assert np.linalg.norm(tool - gp.target_position, axis=1)[ok].max() < IK_TOL
    summary = gp.summary()
    assert summary["ik_unreachable"] == int((~ok).sum()) and summary["duration_s"] == gp.plan.duration


def test_a_plan_from_home_in_a_scene_given_by_its_box_places(demos, arm):
    robot, model = arm
    X_world_base = RigidTransform(RollPitchYaw(0, 0, 0.3), [0.2, -0.1, 0.0])
    X_base_task = X_BASE_TASK[robot.name]
    shelf = (X_world_base @ X_base_task).translation()
    table = X_world_base @ X_base_task @ np.array([0.9, 0.05, -0.5])  # closer than demonstrated (1.03-1.09 m)
    X_world_task, table_task = scene_task_frame(shelf, table)
    assert np.allclose(table_task, [np.hypot(0.9, 0.05), 0, -0.5], atol=1e-9)
    gp = grasp_plan(demos[0], robot, X_world_task, X_world_base=X_world_base, table_place=table_task, start="home",
                    model=model, ik_dt=IK_DT)
    assert np.abs(gp.plan.q[0] - robot.home).max() < robot.safety.start_tolerance
    assert gp.ik.reachable.mean() > 0.8 and gp.plan.check_limits(robot.limits).ok
    end = (X_world_base.inverse() @ X_world_task).multiply(gp.skill.table_place + gp.skill.release_offset)
    assert np.linalg.norm(model.tcp_pose(gp.plan.q[-1]).translation() - end) < IK_TOL


def test_a_lead_in_from_home_keeps_the_limits_and_shifts_the_gripper(arm, arm_plans):
    robot, _ = arm
    plan = arm_plans[0].plan
    led = with_lead_in(plan, robot.home, robot)
    T = led.meta["lead_in_s"]
    assert np.allclose(led.q[0], robot.home) and np.allclose(led.sample([T + 1.0]), plan.sample([1.0]), atol=1e-9)
    assert led.check_limits(robot.limits).ok and led.duration == pytest.approx(plan.duration + T)
    assert np.allclose(np.array(led.meta["gripper"]["t"][1:]) - T, plan.meta["gripper"]["t"])
