"""vMCI segmentation, the zero-velocity baseline, border scoring and the segmentation CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.special import gammaln

from besdrake.cli import main
from besdrake.segmentation import VMCI, SegmentationError, ZeroVelocitySegmenter
from besdrake.segmentation.evaluation import manual_borders, match_borders, score_borders
from besdrake.mocap.segments_io import Segment


def min_jerk_sequence(durations, pauses, freq=100.0, seed=0, noise=0.002):
    """3-D positions: min-jerk movements of the given durations between random targets,
    separated by pauses; returns positions and the true border sample indices."""
    rng = np.random.default_rng(seed)
    x = [np.zeros(3)]
    borders = []
    pos = rng.normal(0, 0.3, 3)
    for k, (d, p) in enumerate(zip(durations, pauses)):
        n = int(round(d * freq))
        target = pos + rng.normal(0, 0.3, 3) + 0.2 * np.sign(rng.normal(size=3))
        tau = np.arange(1, n + 1) / n
        s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
        seg = pos[None] + s[:, None] * (target - pos)[None]
        if k > 0:
            borders.append(len(x))
        x.extend(seg)
        pos = target
        m = int(round(p * freq))
        if m:
            borders.append(len(x))
            x.extend([pos] * m)
    x = np.array(x[1:]) + rng.normal(0, noise, (len(x) - 1, 3))
    return x, np.array(borders) - 1


def test_sequenced_dmps_has_one_border_at_the_subgoal(shared_data):
    d = np.loadtxt(shared_data / "sequenced_dmps.csv", delimiter=",")
    freq = 1.0 / np.mean(np.diff(d[:, 0]))
    for seg in (VMCI(input="velocity", frequency=freq), VMCI(input="position", frequency=freq)):
        column = d[:, 2] if seg.input == "velocity" else d[:, 1]
        borders = seg.fit_predict(column)
        assert len(borders) == 1
        assert abs(d[borders[0], 0] - 0.4) <= 0.05


def test_min_jerk_sequence_borders_are_found():
    durations = [0.8, 1.1, 0.6, 0.9, 1.3, 0.7]
    x, true = min_jerk_sequence(durations, [0.0] * 6, seed=3)
    seg = VMCI(frequency=100.0).fit(x)
    assert len(seg.borders_) == len(true)
    assert np.max(np.abs(seg.borders_ - true)) <= 3  # 30 ms
    assert seg.segments_[0][0] == 0 and seg.segments_[-1][1] == len(x) - 1


def test_pauses_become_rest_segments():
    x, true = min_jerk_sequence([0.8, 1.0, 0.9], [0.8, 0.8, 0.0], seed=5)
    seg = VMCI(frequency=100.0).fit(x)
    models = seg.result_.segment_models
    assert "rest" in models and "movement" in models
    # both ends of each pause are borders
    assert match_borders(seg.borders_, true, tolerance=8) == len(true)


def reference_segmentation(v, freq, seg: VMCI):
    """Exhaustive Viterbi with direct (non-incremental) regressions: the model of VMCI with
    ``rest_log_prior=None, open_ends=False`` (and no border rules) evaluated independently."""
    v = v / np.sqrt(np.mean(np.sum(v**2, axis=1)))
    n, d = v.shape
    dt = 1.0 / freq
    lmin = max(2, int(round(seg.min_length_s * freq)))
    nu, gamma = seg.nu, seg.nu * seg.noise_ratio**2
    var = (seg.weight_ratio / seg.noise_ratio) ** 2
    p = 1.0 / (seg.mean_length_s * freq)
    pen = np.log(p) - np.log1p(-p)

    def loglik(s, t):
        L = t - s
        tau = (np.arange(L) + 0.5) / L
        phi = np.stack([16 * tau**2 * (1 - tau) ** 2 * (2 * tau - 1) ** k for k in range(seg.n_basis)], axis=1)
        A = phi.T @ phi + np.eye(seg.n_basis) / var
        y = v[s:t]
        b = phi.T @ y
        rss = np.sum(y * y) - np.sum(b * np.linalg.solve(A, b))
        N = L * d
        logdet = 0.5 * (-np.linalg.slogdet(A)[1] - seg.n_basis * np.log(var))
        return (-0.5 * N * np.log(np.pi) - gammaln(nu / 2) + 0.5 * nu * np.log(gamma)
                - 0.5 * (N + nu) * np.log(gamma + rss) + gammaln(0.5 * (N + nu)) + d * logdet)

    V = np.full(n + 1, -np.inf)
    V[0] = 0.0
    back = np.zeros(n + 1, dtype=int)
    for t in range(lmin, n + 1):
        for s in range(0, t - lmin + 1):
            if np.isfinite(V[s]):
                c = V[s] + loglik(s, t) + pen
                if c > V[t]:
                    V[t], back[t] = c, s
    borders, t = [], n
    while t > 0:
        t = back[t]
        if t > 0:
            borders.append(t)
    return sorted(borders), V[n]


def test_online_pruned_viterbi_equals_the_exhaustive_reference():
    x, _ = min_jerk_sequence([0.5, 0.7, 0.4], [0.0, 0.0, 0.0], freq=50.0, seed=7, noise=0.004)
    from besdrake.mocap.preprocess import velocity

    v = velocity(x, 50.0)
    seg = VMCI(frequency=50.0, input="velocity", rest_log_prior=None, open_ends=False, min_length_s=0.2, rules=None)
    exact_borders, exact_logp = reference_segmentation(v, 50.0, seg)
    full = VMCI(**{**seg.get_params(), "max_particles": 10**6, "prune_log_ratio": np.inf}).fit(v)
    pruned = seg.fit(v)
    assert list(full.borders_) == exact_borders
    assert full.result_.log_posterior == pytest.approx(exact_logp, rel=1e-9, abs=1e-6)
    assert list(pruned.borders_) == exact_borders
    assert pruned.result_.max_particles_used <= seg.max_particles + int(round(seg.min_length_s * 50)) + 1


def test_pruning_does_not_change_real_segmentation(shared_data):
    from besdrake.mocap.qualisys import read_tsv

    rec = read_tsv(shared_data / "pick_and_place" / "subject2_run1.tsv")
    pruned = VMCI().fit(rec)
    wide = VMCI(max_particles=400, prune_log_ratio=1e3).fit(rec)
    # pruning is an approximation: same borders up to a frame or two, nearly the same posterior
    assert len(pruned.borders_) == len(wide.borders_)
    assert np.max(np.abs(pruned.borders_ - wide.borders_)) <= 2
    assert pruned.result_.log_posterior <= wide.result_.log_posterior + 1e-6
    assert pruned.result_.log_posterior >= wide.result_.log_posterior - 3.0  # nats
    assert pruned.frames_[0] == rec.frames[0]


def test_zero_velocity_baseline_finds_minima_between_movements():
    x, true = min_jerk_sequence([0.8, 1.1, 0.6, 0.9], [0.0] * 4, seed=11)
    seg = ZeroVelocitySegmenter(frequency=100.0).fit(x)
    assert match_borders(seg.borders_, true, tolerance=8) == len(true)


@pytest.mark.parametrize("cls", [VMCI, ZeroVelocitySegmenter])
def test_too_short_and_nan_inputs_are_clear_errors(cls):
    with pytest.raises(SegmentationError, match="too short"):
        cls(frequency=100.0).fit(np.zeros((4, 3)))
    x, _ = min_jerk_sequence([0.8, 1.0], [0.0, 0.0])
    x[40] = np.nan
    with pytest.raises(SegmentationError, match="NaN"):
        cls(frequency=100.0).fit(x)


def test_vmci_bad_parameters_and_motionless_input():
    with pytest.raises(ValueError, match="noise_ratio"):
        VMCI(noise_ratio=-1).fit(np.random.default_rng(0).normal(size=(100, 3)))
    with pytest.raises(ValueError, match="n_basis"):
        VMCI(n_basis=0).fit(np.zeros((100, 3)))
    seg = VMCI(frequency=100.0).fit(np.zeros((200, 3)))  # no motion: one segment
    assert len(seg.borders_) == 0 and seg.segments_ == [(0, 199)]


def test_manual_border_definitions():
    segs = [Segment(10, 50, "a"), Segment(10, 30, "a_part"), Segment(30, 50, "a_part"),
            Segment(62, 90, "b"), Segment(91, 120, "idle")]
    # starts and ends, parts included, 90/91 merged (<= 0.1 s at 60 Hz), recording ends dropped
    assert list(manual_borders(segs, 10, 120, 60.0)) == [30, 50, 62, 90]
    assert list(manual_borders(segs, 10, 120, 60.0, mode="starts")) == [30, 62, 91]
    assert list(manual_borders(segs, 10, 120, 60.0, mode="midgap")) == [30, 56, 91]
    assert list(manual_borders(segs, 10, 120, 60.0, include_parts=False)) == [50, 62, 90]


def test_border_matching_is_one_to_one():
    assert match_borders([10, 11, 12], [11], tolerance=2) == 1
    assert match_borders([10, 20], [12, 19], tolerance=2) == 2
    assert match_borders([10, 20], [13], tolerance=2) == 0
    s = score_borders([100, 200, 300], [101, 260], 60.0, 0.1)
    assert (s.n_matched, s.precision, s.recall) == (1, 1 / 3, 1 / 2)
    assert s.f1 == pytest.approx(0.4)


def test_real_subject2_border_f1(shared_data, tmp_path):
    """Default vMCI on subject 2 (measured F1 0.930 / 0.873 within 0.2 / 0.1 s): a regression guard."""
    for f in sorted((shared_data / "pick_and_place").glob("subject2_*")):
        (tmp_path / f.name).symlink_to(f)
    from besdrake.segmentation.evaluation import evaluate_segmenter, labelled_recordings

    ev = evaluate_segmenter(VMCI(), labelled_recordings(tmp_path))
    assert ev.f1(0.2) >= 0.90
    assert ev.f1(0.1) >= 0.83
    assert ev.data_s / ev.cpu_s > 20  # faster than real time (loose: shared machine)
    # without the default dip rule, the short minimum movement length splits slow movements
    bare = evaluate_segmenter(VMCI(rules=None), labelled_recordings(tmp_path))
    assert bare.f1(0.2) < ev.f1(0.2) - 0.05


def test_cli_segment_json(shared_data, capsys):
    path = shared_data / "pick_and_place" / "subject2_run1.tsv"
    assert main(["segment", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    segs = out["segments"]
    assert segs[0]["start_frame"] == 625 and segs[-1]["end_frame"] == 1098
    assert all(a["end_frame"] == b["start_frame"] for a, b in zip(segs, segs[1:]))
    assert all(s["end_time"] > s["start_time"] for s in segs)
    assert 5 <= len(segs) <= 12


def test_cli_errors(tmp_path, capsys):
    assert main(["segment", str(tmp_path / "missing.tsv"), "--json"]) == 2
    assert "no such file" in capsys.readouterr().err
    assert main(["eval", "segmentation", "--data", str(tmp_path), "--json"]) == 2
    assert "manually_segmented" in capsys.readouterr().err


def test_cli_eval_segmentation(shared_data, tmp_path, capsys):
    for name in ("subject2_run1", "subject2_run2"):
        for suffix in (".tsv", "_manually_segmented.json"):
            (tmp_path / (name + suffix)).symlink_to(shared_data / "pick_and_place" / (name + suffix))
    assert main(["eval", "segmentation", "--data", str(tmp_path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n_recordings"] == 2
    for method in ("vmci", "zero_velocity"):
        for tol in ("0.1", "0.2"):
            s = out[method]["scores"][tol]
            assert 0.0 <= s["precision"] <= 1.0 and 0.0 <= s["recall"] <= 1.0
        assert out[method]["scores"]["0.2"]["f1"] >= out[method]["scores"]["0.1"]["f1"]
    assert out["vmci"]["scores"]["0.2"]["f1"] > 0.7


def test_cli_segment_reports_unusable_recordings(tmp_path, capsys):
    from besdrake.mocap.qualisys import write_tsv
    from besdrake.mocap.recording import MocapRecording

    x, _ = min_jerk_sequence([0.8, 1.0], [0.0, 0.0], freq=60.0)
    names = ["Back top", "Back right", "Back left", "Hand top", "Hand right", "Hand left"]
    back = np.array([[0, 0, 1.4], [0, -0.1, 1.2], [0, 0.1, 1.2]])
    pos = np.concatenate([np.broadcast_to(back, (len(x), 3, 3)),
                          np.stack([x + [0.5, 0, 1.0]] * 3, axis=1) + [[0, 0, 0.02], [0, -0.02, 0], [0, 0.02, 0]]], axis=1)
    never = pos.copy()
    never[:, names.index("Hand left")] = np.nan
    write_tsv(MocapRecording(names, never, 60.0), tmp_path / "never.tsv")
    assert main(["segment", str(tmp_path / "never.tsv"), "--json"]) == 2
    assert "Hand left" in capsys.readouterr().err
    gap = pos.copy()
    gap[30:90, names.index("Hand top")] = np.nan  # a 1 s gap: too long to fill
    write_tsv(MocapRecording(names, gap, 60.0), tmp_path / "gap.tsv")
    assert main(["segment", str(tmp_path / "gap.tsv"), "--json"]) == 2
    assert "Hand top" in capsys.readouterr().err
    short = pos[:10]
    write_tsv(MocapRecording(names, short, 60.0), tmp_path / "short.tsv")
    assert main(["segment", str(tmp_path / "short.tsv"), "--json"]) == 2
    assert "too short" in capsys.readouterr().err
    write_tsv(MocapRecording(names, pos, 60.0), tmp_path / "ok.tsv")
    assert main(["segment", str(tmp_path / "ok.tsv"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert len(out["segments"]) >= 2


def test_rest_border_refinement_moves_borders_to_the_speed_level():
    from besdrake.segmentation.vmci import VMCIResult, refine_rest_borders

    t = np.arange(100)
    speed = np.where(t < 60, np.exp(-0.5 * ((t - 30) / 10.0) ** 2), 0.0)  # bell, then rest
    res = VMCIResult(borders=np.array([70]), n_samples=100, segment_models=["movement", "rest"])
    out = refine_rest_borders(res, speed, level=0.1, max_shift=30)
    # the speed falls below 10% of the peak at t = 52 (30 + 10 * sqrt(2 ln 10) = 51.5)
    assert out.borders[0] == 52
    # a movement -> movement border is never moved
    res = VMCIResult(borders=np.array([70]), n_samples=100, segment_models=["movement", "movement"])
    assert refine_rest_borders(res, speed, 0.1, 30).borders[0] == 70
