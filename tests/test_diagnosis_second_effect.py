"""Where a second effect fits better but is not claimed, the answer names the values of the named cause that the second
effect could account for (besdrake.diagnosis.verdict.second_effect_shift, name_second_effect_shift): benchmark seed 5,
full logs, trial 41 in miniature (a joint-5 offset of 0.032 rad beside the hidden joint-3 offset is 0.010 rad once a
smaller ball is fitted beside it)."""

from types import SimpleNamespace

import numpy as np

from besdrake.diagnosis import fitting
from besdrake.diagnosis.verdict import name_second_effect_shift, second_effect_shift

J2 = fitting.ParamSpec("joint_offset", "joint2", 0.0, -0.1, 0.1, 0.01, "rad")
J3 = fitting.ParamSpec("joint_offset", "joint3", 0.0, -0.1, 0.1, 0.01, "rad")
J5 = fitting.ParamSpec("joint_offset", "joint5", 0.0, -0.1, 0.1, 0.01, "rad")
MASS = fitting.ParamSpec("ball", "mass", 0.05, 0.03, 0.2, 0.005, "kg")
RADIUS = fitting.ParamSpec("ball", "radius", 0.035, 0.028, 0.045, 0.001, "m")


def _fit(effects, specs, theta, refined=True) -> fitting.CandidateFit:
    theta = np.asarray(theta, dtype=float)
    return fitting.CandidateFit(effects=effects, specs=specs, theta=theta, stderr=np.full(len(theta), 1e-3), chi2=500.0, n=600,
                                k=len(theta), refined=refined)


def test_the_named_values_a_second_effect_moves_are_found():
    single = _fit(("joint_offset",), [J2, J3, J5], [-0.0092, -0.0743, 0.0319])
    J4 = fitting.ParamSpec("joint_offset", "joint4", 0.0, -0.1, 0.1, 0.01, "rad")
    J6 = fitting.ParamSpec("joint_offset", "joint6", 0.0, -0.1, 0.1, 0.01, "rad")
    pair = _fit(("joint_offset", "ball"), [J3, J4, J5, J6, MASS, RADIUS], [-0.0716, 0.02, 0.0101, 0.0003, 0.0503, 0.0316])
    shift = second_effect_shift(single, pair)
    assert shift["added"] == {"ball.radius": 0.0316}  # the mass (0.3 g off) and joint 6 (0.3 mrad) hardly move: left out
    # joint 5 loses two thirds of its deviation, joint 2 all of it (the pair leaves it out), joint 4 only the pair
    # moves; joint 3 hardly moves
    assert set(shift["moved"]) == {"joint_offset.joint2", "joint_offset.joint4", "joint_offset.joint5"}
    assert shift["moved"]["joint_offset.joint4"] == {"named": 0.0, "with_second": 0.02}
    assert shift["moved"]["joint_offset.joint5"] == {"named": 0.0319, "with_second": 0.0101}
    assert shift["moved"]["joint_offset.joint2"]["with_second"] == 0.0


def test_the_answer_says_it_only_where_the_second_effect_moves_a_named_value():
    single = _fit(("joint_offset",), [J3, J5], [-0.0743, 0.0319])
    moving = _fit(("joint_offset", "ball"), [J3, J5, RADIUS], [-0.0716, 0.0101, 0.0316])
    still = _fit(("joint_offset", "ball"), [J3, J5, RADIUS], [-0.0740, 0.0300, 0.0340])
    for pair, says in ((moving, True), (still, False)):
        causes = [SimpleNamespace(effects=f.effects) for f in (single, pair)]
        v = SimpleNamespace(second=causes[1], fits=[single, pair], causes=causes, best_fit=single, basis={}, text="explained by joint_offset")
        name_second_effect_shift(v)
        assert ("joint_offset.joint5 0.0319 -> 0.0101" in v.text) is says
        assert ("ball.radius 0.0316" in v.text) is says
        assert v.basis["second_effect"]["effects"] == ["joint_offset", "ball"]
    # a second effect whose own values stay near nominal, moving a named value all the same: no empty list
    quiet = _fit(("joint_offset", "ball"), [J3, J5, RADIUS], [-0.0716, 0.0101, 0.0351])
    v = SimpleNamespace(second=causes[1], fits=[single, quiet], causes=causes, best_fit=single, basis={}, text="x")
    name_second_effect_shift(v)
    assert "fitted as joint_offset + ball the named values move (joint_offset.joint5 0.0319 -> 0.0101)" in v.text
    # no second effect, or one never refined: nothing said
    for second, refined in ((None, True), (causes[1], False)):
        pair = _fit(("joint_offset", "ball"), [J3, J5, RADIUS], [-0.0716, 0.0101, 0.0316], refined=refined)
        v = SimpleNamespace(second=second, fits=[single, pair], causes=[causes[0], causes[1]], best_fit=single, basis={}, text="x")
        name_second_effect_shift(v)
        assert v.text == "x" and "second_effect" not in v.basis
