"""Figures of an imitated segment: demonstrated vs reproduced tool path, joints against limits."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from besdrake._io import save_figure as _save_figure
from besdrake.embodiment.kinematics import KinematicModel, mount_to_transform
from besdrake.embodiment.record_mapping import HandTrajectory


def plot_imitation(result, hand: HandTrajectory, welded: KinematicModel, path: str | Path) -> Path:
    """Write a PNG: the demonstrated hand path and the DMP's tool path in the robot's base frame
    (side and top views), and the joint trajectories with their position and velocity limits."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    X_BS = mount_to_transform(result.sync.mount).inverse()
    R = X_BS.rotation().matrix()
    demo = hand.position @ R.T + X_BS.translation()
    plan = result.plan
    tcp = np.array([welded.tcp_pose(q).translation() for q in plan.q])

    robot = welded.robot
    rows = max(3, -(-robot.n_joints // 2))
    fig = plt.figure(figsize=(13, 8 * rows / 3))
    grid = fig.add_gridspec(rows, 3)
    ax_side = fig.add_subplot(grid[0, 0])
    ax_top = fig.add_subplot(grid[1, 0])
    for ax, (i, j), title in ((ax_side, (0, 2), "side (x-z)"), (ax_top, (0, 1), "top (x-y)")):
        ax.plot(demo[:, i], demo[:, j], "o", ms=3, label="demonstrated hand")
        ax.plot(tcp[:, i], tcp[:, j], "-", label="DMP tool path")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(title)
        ax.set_xlabel("m")
    ax_side.legend(fontsize=7)
    for k in range(robot.n_joints):
        ax = fig.add_subplot(grid[k // 2, 1 + k % 2])
        lo, hi = robot.position_limits[k]
        ax.plot(plan.t, plan.q[:, k], label="q")
        ax.axhline(lo, color="r", lw=0.8)
        ax.axhline(hi, color="r", lw=0.8)
        if plan.qd is not None:
            ax2 = ax.twinx()
            ax2.plot(plan.t, plan.qd[:, k], color="g", lw=0.8)
            ax2.axhline(robot.velocity_limits[k], color="g", ls=":", lw=0.8)
            ax2.axhline(-robot.velocity_limits[k], color="g", ls=":", lw=0.8)
            ax2.tick_params(labelsize=6)
        ax.set_title(f"{robot.joint_names[k]} (rad; green: rad/s)", fontsize=8)
        ax.tick_params(labelsize=6)
    s = result.summary()
    fig.suptitle(
        f"{result.name}: T = {s['execution_time_s']:.2f} s (limited by {s['time_scaling_limited_by']}), "
        f"IK residual {1000 * s['ik_max_position_residual_m']:.2f} mm / {s['ik_max_angle_residual_deg']:.1f} deg, "
        f"{'executable' if s['executable'] else 'NOT executable'}"
    )
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _save_figure(fig, path, dpi=80)
    plt.close(fig)
    return path
