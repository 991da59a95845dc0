"""Backwards-compatible import path (a re-export): the default throws live in
:mod:`besdrake.tasks.throwing.throws`."""

from besdrake.tasks.throwing.throws import START_POSE, SWING, default_throw, min_jerk_plan, side_throw, swing_time

__all__ = ["default_throw", "side_throw", "min_jerk_plan", "swing_time", "START_POSE", "SWING"]
