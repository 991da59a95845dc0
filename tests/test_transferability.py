"""The Transferability Approach: Pareto machinery, behaviour descriptor, transfers, success, resume."""

from __future__ import annotations

import gc

import numpy as np
import pytest

from besdrake.sim import Rollout, make_executor
from besdrake.tasks.throwing.throws import default_throw
from besdrake.tasks.throwing.descriptor import DESCRIPTOR_NAMES, behaviour_descriptor
from besdrake.transfer.lab import SafetyGate
from besdrake.transfer.log import LabLog
from besdrake.transfer.measurement import plan_hash
from besdrake.transfer.transferability import (
    OffsetSurrogate,
    TransferabilityApproach,
    TransferabilityConfig,
    crowding_distance,
    nondominated_ranks,
)
from besdrake.tasks.throwing.lab import VirtualLab


from besdrake.robot import load_robot

COMPI = load_robot("compi")


def to_plan(theta: np.ndarray):
    """A cheap 3-parameter stand-in for the 49 DMP parameters: the default throw."""
    return default_throw(amplitude=float(theta[0]), yaw=float(theta[1]), accel=float(theta[2]))


SCALES = np.array([0.02, 0.02, 0.5])
BOUNDS = np.array([[0.1, 1.0], [-0.5, 0.5], [15.0, 19.5]])
SMALL = dict(population=6, max_transfers=3, final_best_in_lab=1, final_pareto=1, final_repetitions=1)


@pytest.fixture(scope="module")
def seed_theta():
    """Amplitude that lands the default throw 2 m out in the nominal simulation."""
    rollout = Rollout("nominal")
    amps = np.array([0.4, 0.45, 0.5])
    xs = [rollout.rollout(default_throw(amplitude=a)).touchdown[0] for a in amps]
    return np.array([[float(np.interp(2.0, xs, amps)), 0.0, 19.0]])


def _offline(config: TransferabilityConfig | None = None) -> TransferabilityApproach:
    """A search without simulation or lab, seeded at the default throw: for its bookkeeping and probabilities."""
    return TransferabilityApproach(to_plan, np.array([[0.45, 0.0, 19.0]]), SCALES, BOUNDS, None, None, np.random.default_rng(0), config)


def test_nondominated_ranks_and_crowding():
    F = np.array([[0, 3], [1, 1], [3, 0], [2, 2], [3, 3]], dtype=float)
    assert nondominated_ranks(F).tolist() == [0, 0, 0, 1, 2]
    crowd = crowding_distance(F[:3])
    assert np.isinf(crowd[0]) and np.isinf(crowd[2]) and np.isfinite(crowd[1])


def test_descriptor_has_17_finite_features_also_when_the_ball_is_not_thrown():
    rollout = Rollout("nominal")
    plan = default_throw(amplitude=0.45)
    d = behaviour_descriptor(plan, rollout.rollout(plan))
    assert d.shape == (17,) == (len(DESCRIPTOR_NAMES),) and np.isfinite(d).all()
    assert 0 < d[0] < plan.duration  # released during the plan
    weak = default_throw(amplitude=0.05, accel=2.0)
    assert np.isfinite(behaviour_descriptor(weak, rollout.rollout(weak, limits="flag"))).all()


def test_with_a_faithful_simulation_the_first_transfer_succeeds_three_times(seed_theta):
    lab = SafetyGate(VirtualLab("diagrams/labs/ideal_lab.yaml"))
    with make_executor("serial", scenario="nominal") as executor:
        result = TransferabilityApproach(
            to_plan, seed_theta, SCALES, BOUNDS, executor, lab, np.random.default_rng(0), TransferabilityConfig(**SMALL)
        ).run()
    assert result.transfers_until_success == 3  # one transfer and two repetitions
    first = result.transfers[0]
    assert first.kind == "transfer" and first.disparity < 1e-6 and first.lab_target_distance < 0.1
    assert [t.kind for t in result.transfers[:3]] == ["transfer", "repeat", "repeat"]
    assert len(result.final) == 2 and all(f["reliable"] for f in result.final)


def test_nan_seeds_are_refused():
    with pytest.raises(ValueError, match="NaN"):
        TransferabilityApproach(to_plan, np.array([[np.nan, 0, 19]]), SCALES, BOUNDS, None, None, np.random.default_rng(0))


class _Interrupting:
    """A lab that dies (KeyboardInterrupt) before its ``fail_at``-th execution, counting calls."""

    def __init__(self, lab, fail_at: int | None) -> None:
        self.lab, self.fail_at, self.calls, self.robot = lab, fail_at, 0, lab.robot

    def description(self):
        return self.lab.description()

    def execute(self, plan, trial=None):
        if self.fail_at is not None and self.calls == self.fail_at:
            raise KeyboardInterrupt
        self.calls += 1
        return self.lab.execute(plan, trial=trial)


def _search(tmp, lab, seed_theta, executor):
    log_dir = tmp / "log"
    log = LabLog.open(log_dir) if (log_dir / "log.json").is_file() else LabLog.create(log_dir, lab.description())
    cfg = TransferabilityConfig(**(SMALL | {"stop_on_success": False}))
    return TransferabilityApproach(
        to_plan, seed_theta, SCALES, BOUNDS, executor, lab, np.random.default_rng(1), cfg, log=log, out_dir=tmp
    ), log


def test_a_killed_search_resumes_without_repeating_or_losing_lab_trials(tmp_path, seed_theta):
    with make_executor("serial", scenario="nominal") as executor:
        ref, _ = _search(tmp_path / "ref", SafetyGate(VirtualLab("diagrams/labs/default_lab.yaml")), seed_theta, executor)
        expected = [t.plan_hash for t in ref.run().transfers]

        first = _Interrupting(SafetyGate(VirtualLab("diagrams/labs/default_lab.yaml")), fail_at=2)
        search, first_log = _search(tmp_path / "run", first, seed_theta, executor)
        with pytest.raises(KeyboardInterrupt) as killed:
            search.run()
        del killed, search, first_log  # the "killed process" lets go of its log and the log's writer lock
        gc.collect()
        second = _Interrupting(SafetyGate(VirtualLab("diagrams/labs/default_lab.yaml")), fail_at=None)
        search, log = _search(tmp_path / "run", second, seed_theta, executor)
        result = search.run()
    assert [t.plan_hash for t in result.transfers] == expected
    assert first.calls + second.calls == len(expected) == len(log)
    assert [plan_hash(m.plan) for m in log.measurements()] == expected


def test_offset_surrogate_learns_a_behaviour_dependent_offset():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(30, 17))
    offsets = np.column_stack([-0.1 - 0.05 * X[:, 0], 0.02 * X[:, 1]])
    surrogate = OffsetSurrogate()
    assert np.allclose(surrogate.predict(X[:2]), 0.0)  # nothing measured: no offset
    surrogate.add(X[0], offsets[0])
    assert np.allclose(surrogate.predict(X[1:3]), offsets[0])  # one trial: its offset everywhere
    for x, o in zip(X[1:], offsets[1:]):
        surrogate.add(x, o)
    Xt = rng.normal(size=(20, 17))
    truth = np.column_stack([-0.1 - 0.05 * Xt[:, 0], 0.02 * Xt[:, 1]])
    err = np.abs(surrogate.predict(Xt) - truth)
    assert err[:, 0].mean() < 0.5 * np.abs(truth[:, 0] - truth[:, 0].mean()).mean() + 0.01


def test_unknown_transfer_choice_is_refused():
    with pytest.raises(ValueError, match="transfer_choice"):
        TransferabilityConfig(transfer_choice="random")


def test_predicted_choice_aims_past_the_target_when_the_lab_throws_short(seed_theta):
    """The default lab's hidden effects land throws short of the nominal simulation: once the offset
    surrogate has seen that, the transferred plans land beyond the target in simulation (the ball at its habit
    only: the offset model alone decides)."""
    lab = SafetyGate(VirtualLab("diagrams/labs/default_lab.yaml"))
    cfg = TransferabilityConfig(**(SMALL | {"max_transfers": 4, "stop_on_success": False, "final_pareto": 0, "final_best_in_lab": 0,
                                            "population": 8, "transfer_choice": "predicted", "placement_sd": 0.0}))
    with make_executor("serial", scenario="nominal") as executor:
        search = TransferabilityApproach(to_plan, seed_theta, SCALES, BOUNDS, executor, lab, np.random.default_rng(0), cfg)
        result = search.run()
    transfers = [t for t in result.transfers if t.kind == "transfer"]
    assert len(transfers) == 4
    measured = np.array([np.subtract(t.lab_touchdown, t.sim_touchdown) for t in result.transfers])
    assert measured[:, 0].mean() < -0.03  # the lab is short
    assert len(search.offsets.Y) == len(result.transfers)  # repetitions train the offset model too
    assert transfers[0].sim_touchdown[0] == pytest.approx(2.0, abs=0.03)  # nothing measured yet: closest in simulation
    assert max(t.sim_touchdown[0] for t in transfers[1:]) > transfers[0].sim_touchdown[0] + 0.02


def test_likely_choice_stops_retrying_a_plan_that_hits_only_now_and_then():
    """Two plans predicted on target: the one whose lab throws scattered widely (a cliff) is less likely to pass 3/3."""
    from besdrake.transfer.transferability import Transfer

    cfg = TransferabilityConfig(transfer_choice="likely")
    search = _offline(cfg)
    erratic, fresh = np.array([0.45, 0.0, 19.0]), np.array([0.46, 0.0, 19.0])
    h = plan_hash(to_plan(erratic))
    for k, x in enumerate([2.03, 2.28, 1.99, 2.30, 2.02]):  # 3 of 5 within 0.1 m, the others 0.3 m long
        search.transfers.append(Transfer(k, "transfer" if k == 0 else "repeat", erratic.tolist(), h, [2.0, 0.0], [x, 0.0], 0.0, abs(x - 2.0)))
    p = search._success_probabilities(np.array([erratic, fresh]), np.array([[2.0, 0.0], [2.0, 0.0]]))
    assert 0 <= p[0] < p[1] <= 1
    assert p[0] < 0.2  # its own scatter (SD ~0.14 m per axis) makes 3/3 unlikely
    # with no lab trial at all, a plan predicted on target gets the Rayleigh figure of the prior scatter
    fresh_only = _offline(cfg)
    p0 = fresh_only._success_probabilities(fresh[None], np.array([[2.0, 0.0]]))[0]
    assert p0 == pytest.approx((1 - np.exp(-0.1**2 / (2 * 0.05**2))) ** 3, rel=1e-6)


def test_placement_quadrature_has_the_scatter_s_moments():
    from besdrake.tasks.throwing.effects import placement_quadrature

    offsets, weights = placement_quadrature(0.002)
    assert offsets.shape == (9, 2) and np.allclose(offsets[0], 0.0) and weights.sum() == pytest.approx(1.0)
    assert np.allclose(weights @ offsets, 0.0)
    assert np.allclose((weights[:, None, None] * offsets[:, :, None] * offsets[:, None, :]).sum(axis=0), 0.002**2 * np.eye(2))
    assert (weights @ offsets[:, 0] ** 4) == pytest.approx(3 * 0.002**4)  # exact up to the fifth moment
    centre, one = placement_quadrature(0.0)
    assert centre.shape == (1, 2) and one.tolist() == [1.0]


@pytest.mark.parametrize("field, value", [("placement_sd", np.nan), ("placement_sd", -0.001), ("placement_sd", 0.01),
                                          ("mutation_sd_min", 0.0), ("mutation_sd_min", 0.5), ("mutation_sd_min", np.nan)])
def test_bad_placement_or_mutation_settings_are_refused(field, value):
    with pytest.raises(ValueError, match=field):
        TransferabilityConfig(**{field: value})


def test_plans_are_judged_over_the_ball_placements(seed_theta):
    """Every plan is simulated at the 9 placements: the objective is the expected target distance, the shifts are
    each placement's touchdown minus the nominal one, and all rollouts count as simulated episodes."""
    from besdrake.tasks.throwing.effects import ball_placed
    from besdrake.tasks.throwing.effects import placement_quadrature

    thetas = np.vstack([seed_theta, seed_theta + [0.03, 0.02, 0.0]])
    with make_executor("serial", scenario="nominal") as executor:
        search = TransferabilityApproach(to_plan, seed_theta, SCALES, BOUNDS, executor, None, np.random.default_rng(0),
                                         TransferabilityConfig(placement_sd=0.003))
        f1, D, outcomes, shifts = search._evaluate(thetas)
        offsets, weights = placement_quadrature(0.003)
        corner = executor.evaluate([to_plan(thetas[1])], effects={"ball_placement": ball_placed({}, offsets[-1])})[0]
    assert search.sim_episodes == 18 and shifts.shape == (2, 9, 2) and D.shape == (2, 17)
    assert np.allclose(shifts[:, 0], 0.0) and np.abs(shifts[:, 1:]).max() > 1e-3  # the placement moves the touchdown
    assert np.allclose(shifts[1, -1], corner.touchdown - outcomes[1].touchdown)
    td = np.array([o.touchdown for o in outcomes])[:, None, :] + shifts
    assert np.allclose(f1, np.linalg.norm(td - [2.0, 0.0], axis=2) @ weights)


def test_likely_choice_avoids_a_plan_whose_simulated_placements_fall_off_a_cliff():
    """Two fresh plans predicted on target: in one, a placement a few millimetres off sends the ball 0.4 m long."""
    cfg = TransferabilityConfig(transfer_choice="likely")
    search = _offline(cfg)
    weights = search.placement_weights
    robust = np.zeros((9, 2))
    robust[1:, 0] = np.linspace(-0.01, 0.01, 8)
    cliff = robust.copy()
    cliff[[2, 5, 8], 0] = 0.4  # the three placements at +sqrt(3) sd along scoop y
    cliff[4] = np.nan  # and one where the ball does not land at all
    thetas = np.array([[0.45, 0.0, 19.0], [0.46, 0.0, 19.0]])
    p = search._success_probabilities(thetas, np.array([[2.0, 0.0], [2.0, 0.0]]), np.stack([robust, cliff]), weights)
    assert p[1] < 0.6 * p[0]  # 7/36 of the placement mass misses: (29/36)^3 ~ 0.52 of the robust figure
    hit = 1 - np.exp(-0.1**2 / (2 * 0.05**2))  # Rayleigh: a throw on target within 0.1 m at 5 cm per axis
    assert p[1] < ((1 - weights[[2, 4, 5, 8]].sum()) * hit) ** 3 + 1e-9


def test_mutation_steps_range_from_small_to_large():
    search = _offline(TransferabilityConfig(mutation_sd=0.3, mutation_sd_min=0.01))
    parents = np.tile([0.45, 0.0, 17.0], (4000, 1))
    steps = np.linalg.norm((search._mutate(parents) - parents) / SCALES, axis=1) / np.sqrt(3)
    assert np.quantile(steps, 0.1) < 0.03 and np.quantile(steps, 0.9) > 0.15
    single = _offline(TransferabilityConfig(mutation_sd=0.3, mutation_sd_min=0.3))
    expected = parents + 0.3 * SCALES * np.random.default_rng(0).standard_normal(parents.shape)
    assert np.allclose(single._mutate(parents), np.clip(expected, BOUNDS[:, 0], BOUNDS[:, 1]))


def test_a_search_saved_before_placements_resumes_with_its_own_settings(tmp_path, seed_theta):
    """A state written before the placement and mutation settings existed resumes as it ran: one step, no placements."""
    import json

    lab = SafetyGate(VirtualLab("diagrams/labs/default_lab.yaml"))
    old = TransferabilityConfig(**(SMALL | {"max_transfers": 1, "placement_sd": 0.0, "mutation_sd_min": 0.3, "final_pareto": 0,
                                            "final_best_in_lab": 0}))
    with make_executor("serial", scenario="nominal") as executor:
        TransferabilityApproach(to_plan, seed_theta, SCALES, BOUNDS, executor, lab, np.random.default_rng(0), old, out_dir=tmp_path).run()
        state = tmp_path / "transferability_state.json"
        meta = json.loads(state.read_text())
        for key in ("placement_sd", "mutation_sd_min"):
            del meta["config"][key]
        del meta["placement_shifts"]
        state.write_text(json.dumps(meta))
        with pytest.raises(ValueError, match="other settings"):
            TransferabilityApproach(to_plan, seed_theta, SCALES, BOUNDS, executor, lab, np.random.default_rng(0),
                                    TransferabilityConfig(**(SMALL | {"max_transfers": 1})), out_dir=tmp_path)._load()
        again = TransferabilityApproach(to_plan, seed_theta, SCALES, BOUNDS, executor, lab, np.random.default_rng(0), old, out_dir=tmp_path)
        P, f1, D, sim_td, shifts = again._load()
    assert shifts.shape == (len(P), 1, 2) and np.allclose(shifts, 0.0)


def test_transfer_command_refuses_a_placement_scatter_beyond_the_scoop(tmp_path, capsys):
    from besdrake.cli import main
    from besdrake.imitation import save_dmp
    from besdrake.tasks.throwing.template_base import fitted_default_throw

    save_dmp(fitted_default_throw(), tmp_path / "seed.dmp.json")
    code = main(["transfer", "--lab", "diagrams/labs/default_lab.yaml", "--seeds", str(tmp_path / "seed.dmp.json"),
                 "--placement-sd", "0.01", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "placement_sd" in err and "Traceback" not in err
    assert not (tmp_path / "out" / "lab_log").exists()  # refused before the lab is touched


def _thrown(search, theta, touchdowns, sim=(2.0, 0.0)):
    """Record lab trials of ``theta`` (the first a transfer, then repeats) as the search would."""
    from besdrake.transfer.transferability import Transfer

    h = plan_hash(to_plan(np.asarray(theta)))
    for td in touchdowns:
        k = len(search.transfers)
        kind = "transfer" if not any(t.plan_hash == h for t in search.transfers) else "repeat"
        search.transfers.append(Transfer(k, kind, list(theta), h, list(sim), list(td), 0.0, float(np.linalg.norm(np.subtract(td, (2.0, 0.0))))))
        search.offsets.add(np.full(17, float(k)), np.subtract(td, sim))
        search._offset_trials.append(k)


def test_a_cliff_event_is_a_miss_but_poisons_neither_the_scatter_nor_the_offset_model():
    """A plan thrown 5 times lands 4 times within a few cm and once 1.2 m away (the ball rolled out early)."""
    tight = [[2.02, 0.01], [1.98, -0.02], [2.01, 0.03], [1.99, 0.0]]
    cliff = [[0.8, 0.1]]

    def search(radius):
        cfg = TransferabilityConfig(transfer_choice="likely", outlier_radius=radius)
        s = _offline(cfg)
        _thrown(s, [0.45, 0.0, 19.0], tight[:2] + cliff + tight[2:])
        _thrown(s, [0.47, 0.0, 19.0], [[2.0, 0.02]])
        return s

    robust, naive = search(0.25), search(None)
    assert robust.cliff_trials() == {2} and naive.cliff_trials() == set()
    thetas = np.array([[0.45, 0.0, 19.0], [0.46, 0.0, 19.0], [0.47, 0.0, 19.0]])  # the erratic plan, a fresh one, one thrown once
    on_target = np.array([[2.0, 0.0]] * 3)
    p, p_naive = robust._success_probabilities(thetas, on_target), naive._success_probabilities(thetas, on_target)
    assert p[1] > 0.5 and p_naive[1] < 0.1  # the lab's pooled scatter without / with the 1.2 m miss
    assert p[0] < (5 / 6) ** 3 + 1e-9  # the miss still counts against its plan: 4 + 1 of 5 + 1
    assert p[2] > p[0]
    D = np.full((1, 17), 1.5)
    assert np.linalg.norm(robust.predicted_lab_touchdowns(D, [[2.0, 0.0]])[0] - [2.0, 0.0]) < 0.05
    assert naive.predicted_lab_touchdowns(D, [[2.0, 0.0]])[0, 0] < 1.85  # the naive offset model follows the miss


def test_plans_thrown_fewer_than_three_times_have_no_cliff_events():
    s = _offline()
    _thrown(s, [0.45, 0.0, 19.0], [[2.0, 0.0], [0.9, 0.0]])
    assert s.cliff_trials() == set()
    with pytest.raises(ValueError, match="outlier_radius"):
        TransferabilityConfig(outlier_radius=-0.1)


def test_the_final_evaluation_sends_no_pareto_plan_beyond_the_joint_limits():
    """A plan beyond the limits can sit on the Pareto front by its novelty alone: it is not sent to the lab."""
    ok, beyond, near = np.array([0.45, 0.0, 19.0]), np.array([1.5, 0.0, 19.5]), np.array([0.46, 0.0, 19.0])
    assert to_plan(ok).check_limits(COMPI.limits).ok and not to_plan(beyond).check_limits(COMPI.limits).ok
    cfg = TransferabilityConfig(final_best_in_lab=0, final_pareto=4, final_repetitions=1)
    lab = SafetyGate(VirtualLab("diagrams/labs/ideal_lab.yaml"))
    search = TransferabilityApproach(to_plan, ok[None], SCALES, BOUNDS, None, lab, np.random.default_rng(0), cfg)
    P = np.array([ok, beyond, near])
    D = np.array([np.zeros(17), np.full(17, 10.0), np.full(17, 0.1)])  # the plan beyond the limits is the most novel
    F = search._objectives(np.array([0.05, 0.1, 0.3]), D)
    assert nondominated_ranks(F).tolist() == [0, 0, 1]
    final = search._final_evaluation(P, np.array([0.05, 0.1, 0.3]), D, np.array([[2.0, 0.0], [2.1, 0.0], [2.3, 0.0]]))
    assert len(final) == 1 and [t.plan_hash for t in search.transfers] == [plan_hash(to_plan(ok))]
    assert not any("refused_by_safety_gate" in t.flags for t in search.transfers)


class _ShortLab:
    """A lab that throws every plan ``short`` m shorter than its inner lab (a systematic offset no transfer can make
    up for with plans that land on the target in simulation)."""

    def __init__(self, lab, short: float) -> None:
        self.lab, self.short, self.robot = lab, short, lab.robot

    def description(self):
        return self.lab.description()

    def execute(self, plan, trial=None):
        import dataclasses

        m = self.lab.execute(plan, trial=trial)
        return m if m.touchdown is None else dataclasses.replace(m, touchdown=np.asarray(m.touchdown) - [self.short, 0.0])


def test_a_futile_search_ends_once_no_plan_is_likely_to_succeed(seed_theta):
    lab = _ShortLab(SafetyGate(VirtualLab("diagrams/labs/ideal_lab.yaml")), short=0.6)
    runs = {}
    with make_executor("serial", scenario="nominal") as executor:
        for futility_p in (None, 0.01):
            cfg = TransferabilityConfig(**(SMALL | {"max_transfers": 6, "futility_p": futility_p, "futility_transfers": 2}))
            runs[futility_p] = TransferabilityApproach(to_plan, seed_theta, SCALES, BOUNDS, executor, lab, np.random.default_rng(0), cfg).run()
    full, cut = runs[None], runs[0.01]
    plans = lambda r: [t for t in r.transfers if t.kind == "transfer"]  # noqa: E731
    assert len(plans(full)) == 6 and not full.stopped_futile and full.transfers_until_success is None
    assert cut.stopped_futile and 2 <= len(plans(cut)) < 6 and cut.summary()["stopped_futile"]
    assert plans(cut)[0].p_success > 0.01  # before the lab has shown the offset the seed looked likely
    assert all(t.p_success < 0.01 for t in plans(cut)[-2:])
    assert [t.plan_hash for t in plans(cut)] == [t.plan_hash for t in plans(full)][: len(plans(cut))]


@pytest.mark.parametrize("value", [0.0, 1.0, float("nan")])
def test_a_futility_level_outside_0_1_is_refused(value):
    with pytest.raises(ValueError, match="futility_p"):
        TransferabilityConfig(futility_p=value)
