"""Base DMPs fitted to the default throw: stand-ins for a refined throw (tests, benchmarks) and the base of a
behaviour template when no refined throw is given (:mod:`besdrake.search.templates`); where a throw's follow-through
begins (:func:`follow_through_phase`)."""

from __future__ import annotations

import numpy as np

from besdrake.imitation import DMP


def fitted_default_throw(amplitude: float = 0.6, n_weights_per_dim: int = 6) -> DMP:
    """A base DMP fitted to :func:`~besdrake.tasks.throwing.throws.default_throw` (a stand-in for a refined throw,
    for tests and benchmarks without a refinement run)."""
    from besdrake.tasks.throwing.throws import default_throw

    plan = default_throw(amplitude)
    return DMP(plan.q.shape[1], n_weights_per_dim).fit(plan.t, plan.q)


#: Weights per joint of :func:`default_template_base`.
TEMPLATE_BASE_WEIGHTS = 10


def default_template_base() -> DMP:
    """The base of a template when no refined throw is given: the default throw (amplitude 0.6) fitted
    with :data:`TEMPLATE_BASE_WEIGHTS` weights per joint.

    The refinement's 49-parameter DMP (6 weights per joint) smooths the swing: its peak joint speed is
    2.05 rad/s against the throw's 2.28, and within the joint limits it reaches only 2.12 m, short of the
    farthest test contexts (2.31 m). Ten weights reproduce the swing (2.26 rad/s, RMS path error
    3.8 mrad); within the limits that base reaches 2.62 m and, at its slowest execution time, 1.26 m,
    which covers every test context. A template only changes the meta-parameters, so its base need not
    have the refinement's parameter count.
    """
    return fitted_default_throw(0.6, TEMPLATE_BASE_WEIGHTS)


__all__ = ["fitted_default_throw", "default_template_base", "TEMPLATE_BASE_WEIGHTS", "FOLLOW_THROUGH_AFTER", "follow_through_phase"]


#: Where a template's follow-through begins by default: this long (s) after the ball's release (``besdrake learn``'s
#: ``templates.follow_through``, ``besdrake template train --follow-through``).
FOLLOW_THROUGH_AFTER = 0.05


def follow_through_phase(base: DMP, executor, robot, after: float | None = FOLLOW_THROUGH_AFTER) -> float | None:
    """Where the throw's follow-through begins, as a phase of ``base`` (0-1): ``after`` s past the ball's release when
    ``base`` is thrown at its own execution time in ``executor``'s scenario (None: ``after`` is None, the ball was not
    released, or that is past the movement's end). After the release the arm's movement no longer changes the throw, so a template may play that part
    slower where the limits need it (:class:`~besdrake.search.templates.MetaDMP`'s ``follow_through``)."""
    from besdrake.search.templates import MetaDMP

    if after is None:
        return None
    plan = MetaDMP(base, robot).plan(np.array([base.execution_time, base.goal[0]]))
    outcome = executor.evaluate([plan])[0]
    if outcome.release_time is None or not np.isfinite(outcome.release_time):
        return None
    phase = (float(outcome.release_time) + after) / plan.duration
    return phase if phase < 1.0 else None  # released at the very end: no follow-through
