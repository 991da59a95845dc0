"""Parameter parsimony (besdrake.diagnosis.parameters): the named cause keeps only the parameters the log needs."""

import numpy as np
import pytest

from besdrake.diagnosis import fitting, noise
from besdrake.diagnosis.parameters import prune_parameters
from besdrake.tasks.throwing.diagnosis.observables import N_FEATURES, group_slices

JOINTS = [fitting.ParamSpec("joint_offset", f"joint{j}", 0.0, -0.1, 0.1, 0.01, "rad") for j in range(1, 7)]
N_PARAMS = {"joint_offset": 6, "ball": 2}


class _OffsetWorld:
    """Touchdowns only: each joint offset moves every throw's touchdown along its own direction (1 m per rad times a
    per-throw signature), a ball radius too; 5 cm touchdown noise."""

    def __init__(self, seed: int, hidden: dict[str, float]):
        rng = np.random.default_rng(seed)
        self.calls = 0
        self.N, self.sl = 25, group_slices()["touchdown"]
        self.sig = {s.key: rng.normal(0, 1, (self.N, 2)) for s in JOINTS}
        self.sig["ball.radius"] = rng.normal(0, 1, (self.N, 2))
        self.sig["ball.mass"] = rng.normal(0, 1, (self.N, 2))
        self.y0 = np.full((self.N, N_FEATURES), np.nan)
        self.y0[:, self.sl] = rng.normal(0, 1, (self.N, 2))
        self.nm = noise.NoiseModel(sd={"touchdown": 0.05, "ball_pos": 0.01, "ball_vel": 0.05, "ball_acc": 0.3, "ball_rest": 0.003, "joints": 1e-3},
                                   dof={"touchdown": 16, "ball_pos": 0, "ball_vel": 0, "ball_acc": 0, "ball_rest": 0, "joints": 0}, source={})
        y_meas = self.one({"joint_offset": hidden})
        y_meas[:, self.sl] += rng.normal(0, 0.05, (self.N, 2))
        self.prob = fitting.Problem(y_meas, self.y0, self.nm.vector())

    def one(self, effects: dict) -> np.ndarray:
        y = self.y0.copy()
        for name, v in effects.get("joint_offset", {}).items():
            y[:, self.sl] += 3.0 * v * self.sig[f"joint_offset.{name}"]
        y[:, self.sl] += 10.0 * (effects.get("ball", {}).get("radius", 0.035) - 0.035) * self.sig["ball.radius"]
        y[:, self.sl] += 2.0 * (effects.get("ball", {}).get("mass", 0.05) - 0.05) * self.sig["ball.mass"]
        self.calls += 1
        return y

    def features(self, effects_list: list[dict]) -> np.ndarray:
        return np.array([self.one(e) for e in effects_list])

    def fit(self, specs: list[fitting.ParamSpec], effects=("joint_offset",)) -> fitting.CandidateFit:
        """The candidate refined on ``specs`` with its Jacobian at the optimum (as the diagnosis has it)."""
        sens = fitting.compute_sensitivity(specs, self.y0, self.features)
        f = fitting.linear_fit(self.prob, sens, tuple(effects))
        fitting.refine(self.prob, f, self.one, iterations=5)
        return fitting.jacobian_at(self.prob, f, self.features)


def test_parameters_that_only_absorb_noise_are_left_at_nominal():
    both = 0
    for seed in range(8):
        world = _OffsetWorld(seed, {"joint1": 0.04})
        full = world.fit([JOINTS[0], JOINTS[3], JOINTS[5]])  # joint 1 hidden; joints 4 and 6 chosen as well
        assert full.chi2 < world.fit([JOINTS[0]]).chi2  # the spare parameters do lower the chi2 a little
        pruned, dropped = prune_parameters(world.prob, full, world.one, world.nm, ["touchdown"], N_PARAMS, 5)
        assert "joint_offset.joint1" not in dropped and set(dropped) <= {"joint_offset.joint4", "joint_offset.joint6"}
        assert pruned.inactive[len(full.inactive):] == dropped and len(pruned.specs) == 3 - len(dropped)
        assert 0 < pruned.stderr[0] < 0.005 and pruned.theta[0] == pytest.approx(0.04, abs=4 * pruned.stderr[0])
        assert pruned.chi2 == pytest.approx(float(np.sum(world.prob.weighted(pruned.y_fit) ** 2)))
        assert full.k == 3  # the full fit is not changed in place
        both += len(dropped) == 2
    # A spare pair fitted to pure noise moves the touchdowns by 0.07-0.26 noise SD (median over throws): seed 1 keeps one.
    assert both >= 6


def test_a_parameter_the_log_needs_stays():
    world = _OffsetWorld(0, {"joint1": 0.04, "joint4": -0.03})
    full = world.fit([JOINTS[0], JOINTS[3]])
    pruned, dropped = prune_parameters(world.prob, full, world.one, world.nm, ["touchdown"], N_PARAMS, 5)
    assert dropped == [] and pruned is full
    assert full.theta == pytest.approx([0.04, -0.03], abs=0.006)


def test_an_effect_keeps_one_parameter_and_small_effects_are_fitted_whole():
    world = _OffsetWorld(0, {"joint1": 0.0})  # nothing hidden: nothing here is needed, yet each effect keeps one
    radius = fitting.ParamSpec("ball", "radius", 0.035, 0.02, 0.05, 0.001, "m")
    mass = fitting.ParamSpec("ball", "mass", 0.05, 0.03, 0.2, 0.005, "kg")
    full = world.fit([JOINTS[0], JOINTS[1], radius, mass], effects=("ball", "joint_offset"))
    pruned, dropped = prune_parameters(world.prob, full, world.one, world.nm, ["touchdown"], N_PARAMS, 5)
    assert len(dropped) == 1 and dropped[0].startswith("joint_offset.")
    assert sorted(s.key for s in pruned.specs if s.effect == "ball") == ["ball.mass", "ball.radius"]


def test_a_fit_without_predictions_or_jacobian_is_returned_as_it_is():
    world = _OffsetWorld(0, {"joint1": 0.04})
    sens = fitting.compute_sensitivity(JOINTS[:2], world.y0, world.features)
    linear = fitting.linear_fit(world.prob, sens, ("joint_offset",))  # never refined: no predictions
    world.calls = 0
    assert prune_parameters(world.prob, linear, world.one, world.nm, ["touchdown"], N_PARAMS, 5) == (linear, [])
    assert world.calls == 0


def test_the_diagnosis_names_the_pruned_cause_and_keeps_its_verdict():
    """core._name_needed_parameters: the pruned fit replaces the judged one in the verdict (named, refined and held
    out), a note says what was left at nominal, and the verdict's confidence and text stay those of the judged cause."""
    from types import SimpleNamespace

    from besdrake.diagnosis.core import _name_needed_parameters
    from besdrake.diagnosis.verdict import Verdict, rank_causes

    world = _OffsetWorld(0, {"joint1": 0.04})
    full = world.fit([JOINTS[0], JOINTS[3], JOINTS[5]])
    other = world.fit([JOINTS[1]])
    sim = SimpleNamespace(one=lambda e, shift=None: world.one(e), features=lambda effs, shift=None: world.features(effs))
    ev = SimpleNamespace(sim=sim, nm=world.nm, measured_groups=["touchdown"])
    sens = fitting.compute_sensitivity(JOINTS, world.y0, world.features)
    causes = rank_causes(world.prob, [full, other], full, world.nm, ["touchdown"])
    v = Verdict(True, "high", "explained by joint_offset", causes, [full, other], causes[0], full, [])
    notes: list[str] = []
    _name_needed_parameters(v, world.prob, sens, ev, None, 5, notes)
    assert v.best_fit is v.fits[0] and v.best is v.causes[0] and v.fits[1] is other
    assert [p["parameter"] for p in v.best.parameters] == ["joint1"] and v.best.delta_bic == 0.0
    assert v.best.left_nominal[-2:] == ["joint_offset.joint4", "joint_offset.joint6"]
    assert (v.confidence, v.text) == ("high", "explained by joint_offset")
    assert len(notes) == 1 and "joint_offset.joint4, joint_offset.joint6 left at nominal" in notes[0]
    # Nothing to leave out, or nothing explained: the verdict is not touched.
    for verdict in (Verdict(True, "low", "", causes[1:], [other], causes[1], other, []),
                    Verdict(False, "low", "", causes, [full, other], causes[0], full, [])):
        before = (verdict.best, verdict.best_fit, list(verdict.fits))
        _name_needed_parameters(verdict, world.prob, sens, ev, None, 5, notes)
        assert (verdict.best, verdict.best_fit, list(verdict.fits)) == before and len(notes) == 1


def test_rivals_that_beat_the_pruned_cause_are_listed_and_the_answer_is_low():
    """core._list_rivals_beating_the_named: the hidden effect is a ball radius; the verdict was judged on a joint offset
    with spare parameters, which the parsimony step pruned to one offset; the ball, fitted, beats that by BIC, so it is
    listed ("cannot tell"), the answer becomes "low" and says so. A rival that fits worse, the named cause plus an
    effect, and one already listed are not added; an unexplained verdict is left as it is."""
    from types import SimpleNamespace

    from besdrake.diagnosis.core import _list_rivals_beating_the_named
    from besdrake.diagnosis.verdict import Verdict, rank_causes

    radius = fitting.ParamSpec("ball", "radius", 0.035, 0.02, 0.05, 0.001, "m")
    world = _OffsetWorld(3, {"joint1": 0.0})
    world.prob = fitting.Problem(world.one({"ball": {"radius": 0.041}}) + np.pad(
        np.random.default_rng(3).normal(0, 0.05, (world.N, 2)), ((0, 0), (world.sl.start, N_FEATURES - world.sl.stop))), world.y0, world.nm.vector())
    named = world.fit([JOINTS[0]])  # the pruned cause
    ball = world.fit([radius], effects=("ball",))
    worse = world.fit([JOINTS[2]])
    worse.effects = ("gain_scale",)  # a stand-in rival that fits worse than the named cause
    pair = world.fit([JOINTS[0], radius], effects=("ball", "joint_offset"))
    assert ball.bic < named.bic < worse.bic and pair.bic < named.bic
    fits = [named, pair, worse, ball]
    causes = rank_causes(world.prob, fits, named, world.nm, ["touchdown"])
    ev = SimpleNamespace(sim=SimpleNamespace(full_cache={}, key=str), nm=world.nm, measured_groups=["touchdown"], plans=[])
    v = Verdict(True, "high", "explained by joint_offset", causes, fits, causes[0], named, [])
    notes: list[str] = []
    _list_rivals_beating_the_named(v, ev, None, notes)
    assert [a["b"] for a in v.indist] == ["ball"] and v.indist[0]["beats_named"]
    assert v.indist[0]["delta_bic"] == pytest.approx(ball.bic - named.bic)
    assert v.confidence == "low" and "fits worse than ball" in v.text and v.basis["rivals_beating_named"] == ["ball"]
    assert len(notes) == 1 and "ball" in notes[0]
    _list_rivals_beating_the_named(v, ev, None, notes)  # listed once
    assert [a["b"] for a in v.indist] == ["ball"] and len(notes) == 1
    unexplained = Verdict(False, "low", "not explained", causes, fits, causes[0], named, [])
    _list_rivals_beating_the_named(unexplained, ev, None, notes)
    assert unexplained.indist == [] and unexplained.text == "not explained"
