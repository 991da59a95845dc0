"""Base DMPs fitted to the default throw: stand-ins for a refined throw (tests, benchmarks) and the base of a
behaviour template when no refined throw is given (:mod:`besdrake.search.templates`)."""

from __future__ import annotations

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


__all__ = ["fitted_default_throw", "default_template_base", "TEMPLATE_BASE_WEIGHTS"]
