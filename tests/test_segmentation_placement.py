"""Border placement rules after vMCI, learning them on labelled data, tune_vmci, short movements."""

from __future__ import annotations

import json

import numpy as np
import pytest

from besdrake.segmentation import VMCI, BorderRules, apply_rules, learn_rules, tune_vmci
from besdrake.segmentation.evaluation import evaluate_segmenter, labelled_recordings, match_borders
from besdrake.segmentation.placement import RuleCase, score_cases
from besdrake.segmentation.vmci import VMCIResult
from test_segmentation import min_jerk_sequence


def bell(t, centre, width, height=1.0):
    return height * np.exp(-0.5 * ((t - centre) / width) ** 2)


def result(borders, models, n):
    return VMCIResult(borders=np.array(borders), n_samples=n, segment_models=list(models))


def test_identity_rules_change_nothing_and_do_not_mutate():
    t = np.arange(200.0)
    speed = bell(t, 50, 10) + bell(t, 150, 10)
    res = result([100], ["movement", "movement"], 200)
    out = apply_rules(res, speed, 60.0, BorderRules())
    assert list(out.borders) == [100] and out.segment_models == ["movement", "movement"]
    apply_rules(res, speed, 60.0, BorderRules(merge_end_rests=True, dip_ratio=0.9, snap_s=0.5))
    assert list(res.borders) == [100]


def test_end_and_start_levels_move_pause_borders_to_the_speed_level():
    t = np.arange(300.0)
    speed = bell(t, 60, 10) + bell(t, 240, 10)  # movement, pause, movement
    res = result([120, 180], ["movement", "rest", "movement"], 300)
    out = apply_rules(res, speed, 60.0, BorderRules(end_level=0.1, start_level=0.2))
    # exp(-x^2/2) = level at x = sqrt(2 ln(1/level)) widths from the peak
    assert out.borders[0] == int(np.ceil(60 + 10 * np.sqrt(2 * np.log(10))))
    assert out.borders[1] == int(np.ceil(240 - 10 * np.sqrt(2 * np.log(5))))
    assert out.segment_models == ["movement", "rest", "movement"]


def test_dip_ratio_keeps_real_minima_only():
    t = np.arange(300.0)
    deep = bell(t, 75, 15) + bell(t, 225, 15)  # speed ~0 at t = 150
    shallow = bell(t, 120, 30) + bell(t, 180, 30)  # no minimum at t = 150
    res = result([150], ["movement", "movement"], 300)
    assert list(apply_rules(res, deep, 60.0, BorderRules(dip_ratio=0.5)).borders) == [150]
    assert list(apply_rules(res, shallow, 60.0, BorderRules(dip_ratio=0.5)).borders) == []


def test_end_rests_merge_short_rests_collapse_and_snap():
    t = np.arange(400.0)
    speed = bell(t, 100, 12) + bell(t, 200, 12) + bell(t, 330, 12) + 0.01
    res = result([30, 150, 160, 262], ["rest", "movement", "rest", "movement", "movement"], 400)
    rules = BorderRules(merge_end_rests=True, min_rest_s=0.5, snap_s=0.2)
    out = apply_rules(res, speed, 60.0, rules)
    # the leading rest joins the first movement; the 10-sample pause becomes one border at its
    # speed minimum (150); the movement -> movement border snaps to the minimum at 265
    assert list(out.borders) == [150, 265]
    assert out.segment_models == ["movement", "movement", "movement"]


def test_bad_rules_and_inputs_are_clear_errors():
    with pytest.raises(ValueError, match="end_level"):
        BorderRules(end_level=1.5)
    with pytest.raises(ValueError, match="dip_ratio"):
        BorderRules(dip_ratio=-0.1)
    with pytest.raises(ValueError, match="unknown"):
        BorderRules.from_dict({"end_levle": 0.1})
    with pytest.raises(ValueError, match="speed has shape"):
        apply_rules(result([10], ["movement", "movement"], 50), np.ones(40), 60.0, BorderRules())
    with pytest.raises(ValueError, match="rules must be"):
        VMCI(rules="end_level=0.1").fit(np.zeros((100, 3)))
    assert BorderRules.from_dict(BorderRules(end_level=0.1).to_dict()) == BorderRules(end_level=0.1)


def annotated_sequence(seed: int, level: float = 0.15, freq: float = 60.0):
    """3-D velocities: minimum-jerk bells of random duration, direction and peak separated by
    pauses, plus noise; 'manual' borders where each bell crosses ``level`` of its peak (an
    annotator who ends movements early and starts them late). Returns velocities, speed, borders."""
    rng = np.random.default_rng(seed)
    parts, true, t = [], [], 0
    for k in range(5):
        n = int(rng.uniform(0.7, 1.2) * freq)
        tau = (np.arange(n) + 0.5) / n
        shape = 16 * tau**2 * (1 - tau) ** 2
        direction = rng.normal(size=3)
        parts.append(shape[:, None] * rng.uniform(0.5, 1.5) * direction / np.linalg.norm(direction))
        above = np.flatnonzero(shape >= level)
        if k > 0:
            true.append(t + above[0])
        true.append(t + above[-1] + 1)
        t += n
        m = int(rng.uniform(0.6, 1.0) * freq)
        parts.append(np.zeros((m, 3)))
        t += m
    V = np.concatenate(parts) + rng.normal(0, 0.01, (t, 3))
    return V, np.linalg.norm(V, axis=1), np.array(true)


def test_learned_rules_recover_an_annotator_convention_and_transfer():
    seg = VMCI(frequency=60.0, input="velocity", rules=None)
    cases = []
    for seed in (1, 2, 3):
        V, speed, true = annotated_sequence(seed)
        cases.append(RuleCase(seg.fit(V).result_, speed, 60.0, true))
    grid = {"end_level": [0.0, 0.05, 0.15, 0.3], "start_level": [0.0, 0.05, 0.15, 0.3]}
    learned = learn_rules(cases, grid, tolerances=(0.05,))
    assert learned.rules.end_level == 0.15 and learned.rules.start_level == 0.15
    assert learned.f1[0.05] > learned.identity_f1[0.05] + 0.3
    # held out: a recording the rules were not learned on
    V, speed, true = annotated_sequence(7)
    held = [RuleCase(seg.fit(V).result_, speed, 60.0, true)]
    before, after = score_cases(held, BorderRules(), (0.05,))[0.05], score_cases(held, learned.rules, (0.05,))[0.05]
    assert after >= 0.9 and after > before + 0.3


def test_short_fast_movement_between_slow_ones_is_its_own_segment():
    """A 0.15 s movement (a fast throw) between slower ones: both its borders are found
    (the former 0.4 s minimum segment length merged it with a neighbour)."""
    x, true = min_jerk_sequence([0.7, 0.15, 0.6, 0.8], [0.0] * 4, freq=100.0, seed=4)
    seg = VMCI(frequency=100.0).fit(x)
    assert match_borders(seg.borders_, true, tolerance=4) == len(true) == len(seg.borders_)
    # a rest shorter than rest_min_length_s is not a segment of its own
    assert all(b - a >= 40 for (a, b), m in zip(seg.segments_, seg.result_.segment_models) if m == "rest")


def test_json_params_of_the_default_vmci():
    params = VMCI().json_params()
    assert json.loads(json.dumps(params))["rules"]["dip_ratio"] == pytest.approx(0.7)


def test_tune_on_subject1_scores_on_subject2(shared_data, tmp_path):
    """Cross-subject regression guard on a reduced search (the full one is the benchmark's):
    rules chosen on subject 1 include its annotator's early movement ends."""
    folders = {}
    for s in ("subject1", "subject2"):
        folders[s] = tmp_path / s
        folders[s].mkdir()
        for f in sorted((shared_data / "pick_and_place").glob(f"{s}_*")):
            (folders[s] / f.name).symlink_to(f)
    tuned = tune_vmci(labelled_recordings(folders["subject1"]), {"noise_ratio": [0.3]},
                      {"dip_ratio": [0.0, 0.5], "end_level": [0.0, 0.1]})
    assert tuned.rules.end_level == 0.1 and tuned.rules.dip_ratio == 0.5
    assert tuned.train_f1[0.2] > tuned.train_f1_priors[0.2]
    ev = evaluate_segmenter(tuned.segmenter(), labelled_recordings(folders["subject2"]))
    assert ev.f1(0.2) >= 0.88 and ev.f1(0.1) >= 0.80
    assert json.loads(json.dumps(tuned.to_dict()))["params"]["noise_ratio"] == 0.3


def test_cli_eval_tune_on_and_segment_with_the_saved_segmenter(shared_data, tmp_path, capsys):
    from besdrake.cli import main

    for folder, names in (("train", ("subject1_run3", "subject1_run4")), ("test", ("subject2_run1", "subject2_run2"))):
        (tmp_path / folder).mkdir()
        for name in names:
            for suffix in (".tsv", "_manually_segmented.json"):
                (tmp_path / folder / (name + suffix)).symlink_to(shared_data / "pick_and_place" / (name + suffix))
    saved = tmp_path / "tuned.json"
    assert main(["eval", "segmentation", "--data", str(tmp_path / "test"), "--tune-on", str(tmp_path / "train"),
                 "--save-segmenter", str(saved), "--no-baseline", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["tuned_on"] == str(tmp_path / "train")
    assert set(out["tuned"]["rules"]) >= {"dip_ratio", "end_level", "start_level"}
    assert 0.0 <= out["vmci_tuned"]["scores"]["0.1"]["f1"] <= out["vmci_tuned"]["scores"]["0.2"]["f1"] <= 1.0
    assert out["vmci_tuned"]["params"]["rules"] == out["tuned"]["rules"]
    rec = shared_data / "pick_and_place" / "subject2_run1.tsv"
    assert main(["segment", str(rec), "--segmenter", str(saved), "--json"]) == 0
    seg = json.loads(capsys.readouterr().out)
    assert seg["segmenter"]["rules"] == out["tuned"]["rules"] and len(seg["segments"]) >= 2
    # errors
    assert main(["eval", "segmentation", "--data", str(tmp_path / "test"), "--save-segmenter", str(saved)]) == 2
    assert "--tune-on" in capsys.readouterr().err
    assert main(["segment", str(rec), "--segmenter", str(saved), "--method", "zvc"]) == 2
    capsys.readouterr()
    (tmp_path / "bad.json").write_text('{"rules": {}}')
    assert main(["segment", str(rec), "--segmenter", str(tmp_path / "bad.json")]) == 2
    assert "params" in capsys.readouterr().err
