"""The pause rule of the border placement (BorderRules.pause_s / pause_speed)."""

from __future__ import annotations

import numpy as np
import pytest

from besdrake.segmentation import BorderRules, apply_rules, tune_vmci
from besdrake.segmentation.evaluation import evaluate_segmenter, labelled_recordings
from besdrake.segmentation.placement import PAUSE_RULE
from besdrake.segmentation.tuning import DEFAULT_TUNING_RULE_GRID, PAUSE_TUNING_RULE_GRID
from besdrake.segmentation.vmci import VMCIResult

FREQ = 60.0


def result(borders, models, n):
    return VMCIResult(borders=np.array(borders), n_samples=n, segment_models=list(models))


def two_movements(gap: int, n: int = 400, floor: float = 0.01):
    """Speed of two minimum-jerk bells (peak 1 m/s, 60 samples each) ``gap`` samples apart."""
    speed = np.full(n, floor)
    tau = (np.arange(60) + 0.5) / 60
    bell = 16 * tau**2 * (1 - tau) ** 2
    a = 100
    speed[a:a + 60] += bell
    speed[a + 60 + gap:a + 120 + gap] += bell
    return speed


def test_a_long_pause_inside_the_movements_becomes_a_rest_with_a_border_at_each_end():
    speed = two_movements(gap=40)  # 0.67 s between the bells
    n = len(speed)
    res = result([190], ["movement", "movement"], n)  # one border in the pause, as vMCI may put it
    out = apply_rules(res, speed, FREQ, BorderRules(pause_s=0.4, pause_speed=0.05))
    below = np.flatnonzero(speed < 0.05)
    interior = below[(below > 120) & (below < 250)]  # the stretch between the bells
    assert list(out.borders) == [interior[0], interior[-1]]
    assert out.segment_models == ["movement", "rest", "movement"]
    # the speed-level rule then moves both borders out of the pause, towards the movements
    moved = apply_rules(res, speed, FREQ, BorderRules(pause_s=0.4, pause_speed=0.05, end_level=0.2, start_level=0.2))
    assert moved.borders[0] < interior[0] and moved.borders[1] > interior[-1]
    assert speed[moved.borders[0] - 1] >= 0.2 * speed.max() - 1e-12 > speed[moved.borders[0]]
    # the input is not changed
    assert list(res.borders) == [190]


def test_a_pause_is_split_even_where_the_inference_put_no_border():
    speed = two_movements(gap=40)
    out = apply_rules(result([], ["movement"], len(speed)), speed, FREQ, BorderRules(pause_s=0.4))
    assert len(out.borders) == 2 and out.segment_models == ["movement", "rest", "movement"]


def test_short_pauses_existing_rests_and_the_recording_ends_are_left_alone():
    rules = BorderRules(pause_s=0.4, pause_speed=0.05)
    short = two_movements(gap=10)  # 0.17 s below 5 cm/s, shorter than pause_s
    res = result([165], ["movement", "movement"], len(short))
    assert list(apply_rules(res, short, FREQ, rules).borders) == [165]
    long = two_movements(gap=40)
    rest = result([170, 200], ["movement", "rest", "movement"], len(long))  # a rest already there
    out = apply_rules(rest, long, FREQ, rules)
    assert list(out.borders) == [170, 200] and out.segment_models == ["movement", "rest", "movement"]
    # the leading and trailing stretches below the speed (100 and 100+ samples) are not interior
    assert all(120 <= b <= 250 for b in apply_rules(res, long, FREQ, rules).borders)


def test_pause_rule_validation_and_identity():
    with pytest.raises(ValueError, match="pause_speed"):
        BorderRules(pause_s=0.4, pause_speed=0.0)
    with pytest.raises(ValueError, match="pause_s"):
        BorderRules(pause_s=-1.0)
    assert BorderRules(pause_speed=0.1).is_identity  # no pause_s: nothing happens
    assert not BorderRules(**PAUSE_RULE).is_identity
    assert BorderRules.from_dict(BorderRules(**PAUSE_RULE).to_dict()) == BorderRules(**PAUSE_RULE)
    # a segmenter saved before the pause rule existed still loads
    assert BorderRules.from_dict({"dip_ratio": 0.7}).pause_s == 0.0


@pytest.mark.slow
def test_pause_grid_cross_subject_on_the_real_data(shared_data):
    """Tuned on subject 2 and scored on subject 1, the pause rule recovers borders at both ends
    of pauses the default grid merges; the other direction does not lose."""
    recs = labelled_recordings(shared_data / "pick_and_place")
    by = {s: [r for r in recs if r.path.name.startswith(s + "_")] for s in ("subject1", "subject2")}
    f1 = {}
    for grid_name, grid in (("default", DEFAULT_TUNING_RULE_GRID), ("pause", PAUSE_TUNING_RULE_GRID)):
        for a, b in (("subject2", "subject1"), ("subject1", "subject2")):
            tuned = tune_vmci(by[a], rule_grid=grid)
            ev = evaluate_segmenter(tuned.segmenter(), by[b])
            f1[grid_name, b] = (ev.f1(0.2), ev.f1(0.1))
    assert f1["pause", "subject1"][0] > f1["default", "subject1"][0]
    assert f1["pause", "subject1"][1] > f1["default", "subject1"][1]
    assert f1["pause", "subject2"][0] >= f1["default", "subject2"][0] - 1e-9
    assert f1["pause", "subject2"][1] >= f1["default", "subject2"][1] - 1e-9


def test_bench_ceiling_is_a_pareto_front(shared_data, script, monkeypatch):
    """The benchmark's --ceiling: no point of the front is dominated, and the targets flag follows it."""
    from besdrake.mocap.preprocess import preprocess

    bench = script("bench_segmentation")
    monkeypatch.setattr(bench, "VMCI_GRID", {"noise_ratio": [0.3]})
    monkeypatch.setattr(bench, "CEILING_RULE_GRID", {"dip_ratio": [0.0, 0.7], "end_level": [0.0, 0.1],
                                                     "pause_s": [0.0, 0.4]})
    recs = labelled_recordings(shared_data / "pick_and_place")
    recs = [r for r in recs if r.path.name in ("subject1_run4.tsv", "subject2_run5.tsv")]
    pre = {str(r.path): preprocess(r.recording) for r in recs}
    out = bench.ceiling({r.path.name[:8]: [r] for r in recs}, pre, targets=(0.5, 0.5))
    for subject in out.values():
        front = [(p["f1_0.2"], p["f1_0.1"]) for p in subject["pareto_front"]]
        assert subject["n_candidates"] == 8 and 1 <= len(front) <= 8
        assert all(0.0 <= b <= 1.0 and 0.0 <= a <= 1.0 for a, b in front)
        for i, p in enumerate(front):
            assert not any(q[0] >= p[0] and q[1] >= p[1] and q != p for q in front[:i] + front[i + 1:])
        assert subject["reaches_targets"] == any(a >= 0.5 and b >= 0.5 for a, b in front)
