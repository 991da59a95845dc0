"""A synthetic throwing demonstrator: realistic labelled and unlabelled Qualisys recordings.

Each subject (a :class:`SubjectStyle`: body size, strike-out depth, timing, throw arc, noise and
occlusion rates) performs experiments of overhand throws at a target about 2 m in front of them.
Each throw is idle -> strike_out -> throw -> swing_out -> idle, made of minimum-jerk
sub-movements (bell-shaped speed) that overlap a little. The hand is above the shoulder while
throwing; the ball leaves the hand at release with a speed chosen so that it lands near the
target (peak hand speeds of about 3-6.5 m/s) and flies ballistically until it leaves the
capture volume. Markers (the paper's set): ``Back top``, ``Back right``, ``Back left``, ``Shoulder``,
``Elbow``, ``Hand top``, ``Hand right``, ``Hand left``, ``Ball``.

Recordings are sampled at :data:`FREQUENCY` = 100 Hz (a common Qualisys rate; keeps files
small), carry about 1 mm of Gaussian noise and short occlusion gaps (random and pose-dependent,
at most 0.2 s: the labelled files stand for recordings after labelling and gap filling). The
unlabelled variant adds long occlusions (0.5-1 s), ghost markers and shuffled identities
(unnamed trajectory slots, the identity of a slot changing at every gap as a passive system
delivers). The ``_manually_segmented.json`` borders carry a 20 ms annotator jitter; the exact
ones are in the truth.

Everything is seeded: subject ``i`` draws from ``numpy.random.default_rng([seed, i])`` and its
experiment ``j`` from ``default_rng([seed, i, j])``, so any single file can be regenerated.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from besdrake._io import save_npz as _save_npz, write_text as _atomic_write_text
from besdrake.tasks.throwing import arm_model as am
from besdrake.mocap.qualisys import write_tsv
from besdrake.mocap.recording import MocapRecording
from besdrake.mocap.segments_io import Segment, segmentation_path, write_segmentation

FREQUENCY = 100.0
GRAVITY = np.array([0.0, 0.0, -9.81])
MARKER_NAMES = [
    "Back top",
    "Back right",
    "Back left",
    "Shoulder",
    "Elbow",
    "Hand top",
    "Hand right",
    "Hand left",
    "Ball",
]
LABELS = ("idle", "strike_out", "throw", "swing_out")
TARGET_DISTANCE = 2.0  # metres in front of the subject's feet
ANNOTATOR_JITTER_S = 0.02  # spread of the "manual" segment borders around the exact ones


@dataclass
class SubjectStyle:
    """Per-subject parameters of the demonstrator (lengths in metres, times in seconds)."""

    height: float
    upper_arm: float
    forearm: float
    strike_depth: float  # how far behind the shoulder the hand goes (fraction of arm length)
    cock_height: float  # hand height above the shoulder at the end of strike-out (fraction)
    front_reach: float  # hand forward reach at the end of the throw (fraction)
    front_height: float  # hand height above the shoulder at the end of the throw (fraction)
    throw_arc: float  # upward bulge of the throw path (fraction)
    strike_duration: float
    swing_duration: float
    idle_duration: float
    overlap: float  # fraction of a sub-movement overlapped by the next
    release_phase: float  # phase of the throw sub-movement at which the ball leaves the hand
    trunk_yaw_back: float  # radians
    trunk_yaw_forward: float
    trunk_lean: float
    target_offset: float  # subject's systematic over/undershoot (m)
    noise_mm: float  # RMS 3-D marker noise
    gap_rate: float  # random occlusions per marker and second
    ghost_rate: float  # ghost markers per second (unlabelled variant)

    @classmethod
    def sample(cls, rng: np.random.Generator) -> "SubjectStyle":
        height = rng.uniform(1.58, 1.95)
        s = height / 1.75
        cock_height = rng.uniform(0.32, 0.5)
        return cls(
            height=height,
            upper_arm=0.29 * s * rng.uniform(0.95, 1.05),
            forearm=0.26 * s * rng.uniform(0.95, 1.05),
            strike_depth=rng.uniform(0.25, 0.45),
            cock_height=cock_height,
            front_reach=rng.uniform(0.55, 0.72),
            front_height=cock_height + rng.uniform(0.0, 0.12),  # release level or slightly up
            throw_arc=rng.uniform(0.04, 0.14),
            strike_duration=rng.uniform(0.55, 0.9),
            swing_duration=rng.uniform(0.6, 1.0),
            idle_duration=rng.uniform(0.9, 1.6),
            overlap=rng.uniform(0.06, 0.18),
            release_phase=rng.uniform(0.55, 0.68),
            trunk_yaw_back=rng.uniform(0.15, 0.4),
            trunk_yaw_forward=rng.uniform(0.1, 0.3),
            trunk_lean=rng.uniform(0.03, 0.12),
            target_offset=rng.normal(0.0, 0.15),
            noise_mm=rng.uniform(0.6, 1.2),
            gap_rate=rng.uniform(0.05, 0.25),
            ghost_rate=rng.uniform(0.1, 0.4),
        )


@dataclass
class ExperimentTruth:
    """Noise-free ground truth of one synthetic experiment (SI units, quaternions w, x, y, z).

    ``hand_*`` is the hand frame (origin at the hand centre, x to the fingers, z dorsal; the
    hand plate's marker coordinates in it are :data:`besdrake.tasks.throwing.arm_model.HAND_PLATE`),
    ``back_*`` the trunk frame at the back plate origin (x forward, y left, z up;
    :data:`~besdrake.tasks.throwing.arm_model.BACK_PLATE`), ``hand_*_in_back`` the hand pose in the back frame.
    ``segment_*`` are the exact borders (hand-speed minima and sub-movement onsets/ends); the
    ``_manually_segmented.json`` files hold them with annotator jitter (:data:`ANNOTATOR_JITTER_S`).
    """

    time: np.ndarray
    frames: np.ndarray
    hand_position: np.ndarray
    hand_quaternion: np.ndarray
    back_position: np.ndarray
    back_quaternion: np.ndarray
    hand_position_in_back: np.ndarray
    hand_quaternion_in_back: np.ndarray
    shoulder: np.ndarray
    elbow: np.ndarray
    wrist: np.ndarray
    hand_speed: np.ndarray
    clean_positions: np.ndarray  # (n_frames, n_markers, 3) before noise and gaps (NaN: ball absent)
    long_occlusions: np.ndarray  # (n_frames, n_markers) bool: long gaps of the unlabelled variant only
    release_frames: np.ndarray
    release_velocity: np.ndarray  # (n_throws, 3)
    landing_points: np.ndarray  # (n_throws, 3)
    target: np.ndarray  # (3,)
    segment_starts: np.ndarray
    segment_ends: np.ndarray
    segment_labels: list[str]

    def save(self, path: str | Path) -> None:
        data = {k: np.asarray(v) for k, v in asdict(self).items()}
        # Trajectories as float32 (sub-micrometre precision) keep the files small.
        data = {k: (v.astype(np.float32) if v.dtype == np.float64 and v.size > 64 else v) for k, v in data.items()}
        _save_npz(path, **data)

    @classmethod
    def load(cls, path: str | Path) -> "ExperimentTruth":
        with np.load(path) as z:
            kw = {k: (z[k].astype(np.float64) if z[k].dtype == np.float32 else z[k]) for k in z.files}
        kw["segment_labels"] = [str(s) for s in kw["segment_labels"]]
        return cls(**kw)


class SyntheticExperiment(NamedTuple):
    recording: MocapRecording
    segments: list[Segment]
    truth: ExperimentTruth


@dataclass
class _Sub:
    """One minimum-jerk sub-movement of the pose channels."""

    start: float
    duration: float
    delta: np.ndarray  # change of every pose channel
    arc: np.ndarray  # bump added to the wrist (3,), in arm lengths
    label: str


# Pose channels: wrist (3, in arm lengths, trunk frame rel. to shoulder), elbow hint (3),
# pronation, trunk yaw, trunk pitch, wrist flexion (rad).
def _pose_vector(wrist, hint, pron, yaw, pitch, flex=0.0) -> np.ndarray:
    return np.concatenate([wrist, hint, [pron, yaw, pitch, flex]])


class SyntheticSubject:
    """One demonstrator; :meth:`experiment` gives reproducible recordings of it."""

    def __init__(self, seed: int, index: int, n_throws: int = 8, frequency: float = FREQUENCY):
        self.seed, self.index, self.n_throws, self.frequency = seed, index, n_throws, frequency
        self.style = SubjectStyle.sample(np.random.default_rng([seed, index]))

    # ---------------------------------------------------------------- timeline
    def _key_poses(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        st = self.style
        j = lambda scale: rng.normal(0.0, scale)  # noqa: E731 (per-throw variation)
        rest = _pose_vector([0.08 + j(0.02), 0.03 + j(0.02), -0.92], [-0.5, -0.8, 0.0], 0.0, 0.0, 0.0, j(0.1))
        cock = _pose_vector(
            [-st.strike_depth + j(0.03), 0.0 + j(0.02), st.cock_height + j(0.03)],
            [-0.1, -1.0, -0.4],
            0.5 + j(0.05),
            -st.trunk_yaw_back + j(0.03),
            -0.03,
            -0.5 + j(0.1),  # wrist cocked back
        )
        front = _pose_vector(
            [st.front_reach + j(0.03), 0.10 + j(0.02), st.front_height + j(0.03)],
            [0.0, -1.0, -0.6],
            -0.3 + j(0.05),
            st.trunk_yaw_forward + j(0.03),
            st.trunk_lean + j(0.02),
            0.5 + j(0.1),  # wrist snap
        )
        arc_strike = np.array([-0.2, -0.2, 0.0]) * rng.uniform(0.7, 1.3)
        arc_swing = np.array([0.12, 0.15, -0.05]) * rng.uniform(0.7, 1.3)
        return rest, cock, front, arc_strike, arc_swing

    def _timeline(self, rng: np.random.Generator, throw_durations: np.ndarray | None) -> tuple[list[_Sub], float, np.ndarray, np.ndarray]:
        st = self.style
        subs: list[_Sub] = []
        t = rng.uniform(1.0, 1.8)
        release_times = np.zeros(self.n_throws)
        for k in range(self.n_throws):
            rest, cock, front, arc_strike, arc_swing = self._key_poses(rng)
            d1 = st.strike_duration * rng.uniform(0.9, 1.1)
            d2 = 0.3 if throw_durations is None else float(throw_durations[k])
            d3 = st.swing_duration * rng.uniform(0.9, 1.1)
            ov = st.overlap * rng.uniform(0.7, 1.3)
            arc_throw = np.array([0.0, 0.0, st.throw_arc * rng.uniform(0.8, 1.2)])
            subs.append(_Sub(t, d1, cock - rest, arc_strike, "strike_out"))
            t2 = t + d1 * (1 - ov)
            subs.append(_Sub(t2, d2, front - cock, arc_throw, "throw"))
            release_times[k] = t2 + st.release_phase * d2
            t3 = t2 + d2 * (1 - ov)
            subs.append(_Sub(t3, d3, rest - front, arc_swing, "swing_out"))
            t = t3 + d3 + st.idle_duration * rng.uniform(0.75, 1.3)
        rest0 = self._key_poses(np.random.default_rng([self.seed, self.index, 999]))[0]
        return subs, t + rng.uniform(0.5, 1.0), release_times, rest0

    # ---------------------------------------------------------------- kinematics
    def _kinematics(self, time: np.ndarray, subs: list[_Sub], rest0: np.ndarray, sway: np.ndarray, heading: float, base: np.ndarray) -> dict:
        st = self.style
        s = st.height / 1.75
        reach = st.upper_arm + st.forearm
        q = np.tile(rest0, (len(time), 1))
        wrist_arc = np.zeros((len(time), 3))
        for sub in subs:
            tau = (time - sub.start) / sub.duration
            q += min_jerk_outer(tau, sub.delta)
            wrist_arc += am.bump(tau)[:, None] * sub.arc
        q[:, :3] += wrist_arc + sway[:, :3]
        q[:, 7:9] += sway[:, 3:5]
        yaw, pitch = q[:, 7], q[:, 8]
        rot = am.trunk_rotation(yaw, pitch, heading)  # (n, 3, 3)
        hip = base + np.array([0.0, 0.0, 0.95 * s]) + sway[:, 5:8]
        to_world = lambda local: hip + np.einsum("nij,j->ni", rot, local)  # noqa: E731
        shoulder_joint = to_world(np.array([0.0, -0.19 * s, 0.47 * s]))
        wrist_rel = am.soft_reach(q[:, :3] * reach, reach)
        wrist = shoulder_joint + np.einsum("nij,nj->ni", rot, wrist_rel)
        hint = np.einsum("nij,nj->ni", rot, q[:, 3:6])
        elbow = am.two_link_elbow(shoulder_joint, wrist, st.upper_arm, st.forearm, hint)
        hand_rot = am.hand_frame(elbow, wrist, shoulder_joint, q[:, 6])
        hand_rot = np.einsum("nij,njk->nik", hand_rot, Rotation.from_euler("y", q[:, 9:10]).as_matrix())
        hand_centre = wrist + 0.05 * s * hand_rot[:, :, 0]
        # Shoulder marker on the acromion, rising a little as the arm is raised.
        elevation = np.clip((wrist_rel[:, 2] / reach + 0.6) / 1.1, 0.0, 1.0)
        shoulder_marker = shoulder_joint + np.einsum("nij,nj->ni", rot, np.stack(
            [np.zeros_like(elevation), -0.012 * np.ones_like(elevation), 0.035 + 0.03 * elevation], axis=1))
        # Elbow marker on the epicondyle: offset the way the elbow points (away from the
        # shoulder-wrist line), which is continuous while the elbow is flexed.
        sw = am._unit(wrist - shoulder_joint)
        foot = shoulder_joint + np.sum((elbow - shoulder_joint) * sw, axis=1, keepdims=True) * sw
        elbow_marker = elbow + 0.025 * am._unit(elbow - foot)
        back_origin = to_world(np.array([-0.12 * s, 0.0, 0.45 * s]))
        markers = {"Shoulder": shoulder_marker, "Elbow": elbow_marker}
        markers.update(am.plate_points(back_origin, rot, am.BACK_PLATE))
        markers.update(am.plate_points(hand_centre, hand_rot, am.HAND_PLATE))
        ball_in_hand = hand_centre + 0.02 * hand_rot[:, :, 0] - 0.05 * hand_rot[:, :, 2]
        return dict(
            rot=rot, back_origin=back_origin, shoulder=shoulder_joint, elbow=elbow, wrist=wrist,
            hand_rot=hand_rot, hand_centre=hand_centre, markers=markers, ball_in_hand=ball_in_hand,
        )

    def _sway(self, rng: np.random.Generator, time: np.ndarray) -> np.ndarray:
        """Slow postural sway: wrist (arm lengths), yaw, pitch (rad), hip (m); sums of sinusoids."""
        amp = np.array([0.012, 0.012, 0.008, 0.01, 0.006, 0.006, 0.006, 0.002])
        out = np.zeros((len(time), len(amp)))
        for _ in range(3):
            f = rng.uniform(0.08, 0.5, size=len(amp))
            ph = rng.uniform(0, 2 * np.pi, size=len(amp))
            out += np.sin(2 * np.pi * f * time[:, None] + ph) * amp / 3 ** 0.5
        return out

    # ---------------------------------------------------------------- experiment
    def experiment(self, j: int) -> SyntheticExperiment:
        """The ``j``-th experiment (0-based) of this subject: recording, segments, truth."""
        dt = 1.0 / self.frequency
        rng_seed = [self.seed, self.index, j]
        heading = float(np.random.default_rng(rng_seed + [7]).normal(0.0, 0.05))
        base = np.random.default_rng(rng_seed + [8]).normal(0.0, 0.05, size=3) * [1, 1, 0]
        # The target is fixed in the room before the subject turns towards it.
        target = base + np.array([np.cos(heading), np.sin(heading), 0.0]) * (TARGET_DISTANCE + self.style.target_offset)
        subs, time, kin, release_idx, vel = self._aimed_throws(rng_seed, heading, base, target)
        n = len(time)
        markers = kin["markers"]
        markers["Ball"], landing = self._ball(kin, subs, release_idx, vel, np.random.default_rng(rng_seed + [3]), n, dt)
        clean = np.stack([markers[name] for name in MARKER_NAMES], axis=1)
        hand_speed = np.linalg.norm(np.gradient(kin["hand_centre"], dt, axis=0), axis=1)
        frames = np.arange(1, n + 1)
        exact, segments = self._segments(subs, hand_speed, frames, np.random.default_rng(rng_seed + [6]))
        # Noise and gaps.
        noise_rng = np.random.default_rng(rng_seed + [4])
        observed = clean + noise_rng.normal(0.0, self.style.noise_mm / 1000.0 / np.sqrt(3), size=clean.shape)
        short_gaps, long_gaps = self._gap_mask(noise_rng, time, subs)
        observed[short_gaps] = np.nan
        rec = MocapRecording(
            list(MARKER_NAMES), observed, self.frequency, frames, time,
            {"NO_OF_CAMERAS": 7, "DESCRIPTION": f"besdrake synthetic throws: subject {self.index + 1}, experiment {j + 1}",
             "TIME_STAMP": "2026-01-01, 00:00:00\t0.0"},
        )
        truth = _truth(kin, time, frames, hand_speed, clean, long_gaps, release_idx, vel, landing, target, exact)
        return SyntheticExperiment(rec, segments, truth)

    def _aimed_throws(self, rng_seed: list[int], heading: float, base: np.ndarray, target: np.ndarray):
        """The experiment's timeline and kinematics, aimed at ``target``: ``(subs, time, kin, release indices, release
        velocities)``. Pass 0 turns the subject so the throws head for the target (the arm's sweep and the trunk
        rotation send the ball to the left of the facing direction); pass 1 measures the release directions at nominal
        throw durations; pass 2 uses durations that send the ball to the target (release velocity scales as
        1 / duration)."""
        dt = 1.0 / self.frequency
        durations = None
        for _pass in range(3):
            rng = np.random.default_rng(rng_seed)
            subs, t_end, release_times, rest0 = self._timeline(rng, durations)
            time = np.arange(0.0, t_end, dt)
            sway = self._sway(np.random.default_rng(rng_seed + [1]), time)
            kin = self._kinematics(time, subs, rest0, sway, heading, base)
            release_idx = np.minimum(np.round(release_times / dt).astype(int), len(time) - 2)
            vel = (kin["ball_in_hand"][release_idx + 1] - kin["ball_in_hand"][release_idx - 1]) / (2 * dt)
            if _pass == 2:
                break
            if _pass == 0:
                p = kin["ball_in_hand"][release_idx]
                aim = np.arctan2(target[1] - p[:, 1], target[0] - p[:, 0])
                heading -= float(np.mean(np.angle(np.exp(1j * (np.arctan2(vel[:, 1], vel[:, 0]) - aim)))))
                continue
            throw_durs = np.array([s.duration for s in subs if s.label == "throw"])
            durations = np.empty(self.n_throws)
            jitter = np.random.default_rng(rng_seed + [2]).normal(0.0, 0.08, size=self.n_throws)
            for k in range(self.n_throws):
                p = kin["ball_in_hand"][release_idx[k]]
                speed_now = np.linalg.norm(vel[k])
                need = am.ballistic_speed(vel[k] / speed_now, p[2], max(np.linalg.norm(target[:2] - p[:2]) + jitter[k], 0.5))
                durations[k] = np.clip(throw_durs[k] * speed_now / need, 0.12, 0.6)
        return subs, time, kin, release_idx, vel

    def _ball(self, kin: dict, subs: list[_Sub], release_idx: np.ndarray, vel: np.ndarray, ball_rng: np.random.Generator,
              n: int, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """The ball marker (n, 3; NaN where not seen) and the landing points: in the hand from a while before each
        strike-out until release, then ballistic until it leaves the capture volume (or reaches the ground)."""
        ball = np.full((n, 3), np.nan)
        landing = np.zeros((self.n_throws, 3))
        strike_starts = [s.start for s in subs if s.label == "strike_out"]
        prev_end = 0
        for k in range(self.n_throws):
            appear = max(int((strike_starts[k] - ball_rng.uniform(0.4, 0.8)) / dt), prev_end)
            r = release_idx[k]
            ball[appear : r + 1] = kin["ball_in_hand"][appear : r + 1]
            p0, v0 = kin["ball_in_hand"][r], vel[k]
            t_fl = (v0[2] + np.sqrt(v0[2] ** 2 + 2 * 9.81 * max(p0[2] - 0.04, 1e-3))) / 9.81
            landing[k] = p0 + v0 * t_fl + 0.5 * GRAVITY * t_fl**2
            visible_for = min(t_fl, ball_rng.uniform(0.25, 0.45))
            m = int(visible_for / dt)
            tt = np.arange(1, m + 1)[:, None] * dt
            ball[r + 1 : r + 1 + m] = (p0 + v0 * tt + 0.5 * GRAVITY * tt**2)[: max(0, min(m, n - r - 1))]
            prev_end = min(r + 1 + m, n)
        return ball, landing

    def _segments(self, subs: list[_Sub], hand_speed: np.ndarray, frames: np.ndarray,
                  jitter_rng: np.random.Generator) -> tuple[list[Segment], list[Segment]]:
        """The exact segments (borders at the hand-speed minimum where consecutive sub-movements overlap) and the
        "manual" ones: a human annotator places interior borders a little off (Gaussian, ANNOTATOR_JITTER_S)."""
        dt, n = 1.0 / self.frequency, len(frames)
        bounds = [0]
        labels = ["idle"]
        for k in range(self.n_throws):
            so, th, sw = subs[3 * k : 3 * k + 3]
            i_so = int(round(so.start / dt))
            a, b = int(np.floor(th.start / dt)), int(np.ceil((so.start + so.duration) / dt))
            i_th = a + int(np.argmin(hand_speed[a : b + 1]))
            a, b = int(np.floor(sw.start / dt)), int(np.ceil((th.start + th.duration) / dt))
            i_sw = a + int(np.argmin(hand_speed[a : b + 1]))
            i_end = int(round((sw.start + sw.duration) / dt))
            bounds += [i_so, i_th, i_sw, i_end]
            labels += ["strike_out", "throw", "swing_out", "idle"]
        bounds.append(n - 1)
        exact = [Segment(int(frames[bounds[i]]), int(frames[bounds[i + 1]]), labels[i]) for i in range(len(labels))]
        b = np.array(bounds, dtype=float)
        jitter = jitter_rng.normal(0.0, ANNOTATOR_JITTER_S * self.frequency, size=len(b))
        b[1:-1] = np.round(b[1:-1] + jitter[1:-1])
        for i in range(1, len(b) - 1):  # keep every segment at least 2 frames long
            b[i] = np.clip(b[i], b[i - 1] + 2, bounds[i + 1] - 2)
        segments = [Segment(int(frames[int(b[i])]), int(frames[int(b[i + 1])]), labels[i]) for i in range(len(labels))]
        return exact, segments

    def _gap_mask(self, rng: np.random.Generator, time: np.ndarray, subs: list[_Sub]) -> tuple[np.ndarray, np.ndarray]:
        """Occlusions ``(n_frames, n_markers)``: short ones (random, and hand or elbow markers
        hidden in some throws while the hand is behind the head or in front; at most 0.2 s, none
        in the first and last 0.1 s), and long ones (0.5-1 s) kept apart: the labelled files
        stand for recordings after labelling and gap filling, so only the unlabelled variant
        carries the long occlusions (which a labeller flags, as in the paper)."""
        st = self.style
        n, m = len(time), len(MARKER_NAMES)
        dt = 1.0 / self.frequency
        mask = np.zeros((n, m), dtype=bool)
        long_mask = np.zeros((n, m), dtype=bool)
        duration = time[-1] - time[0]
        max_short = max(1, int(0.2 / dt))
        for col in range(m):
            for _ in range(rng.poisson(st.gap_rate * duration)):
                start = rng.integers(0, n)
                length = int(np.clip(rng.lognormal(np.log(0.06), 0.6) / dt, 1, max_short))
                if rng.random() < 0.04:
                    long_mask[start : start + int(rng.uniform(0.5, 1.0) / dt), col] = True
                else:
                    mask[start : start + length, col] = True
        hand_cols = [MARKER_NAMES.index(n_) for n_ in ("Hand top", "Hand right", "Hand left")]
        elbow_col = MARKER_NAMES.index("Elbow")
        for sub in subs:
            if sub.label == "strike_out" and rng.random() < 0.3:
                # The hand passes behind the head: one hand marker is hidden near the end.
                a = int((sub.start + 0.7 * sub.duration) / dt)
                mask[a : a + rng.integers(3, 15), hand_cols[rng.integers(0, 3)]] = True
            if sub.label == "throw" and rng.random() < 0.2:
                a = int((sub.start + 0.3 * sub.duration) / dt)
                mask[a : a + rng.integers(2, 10), elbow_col] = True
        edge = int(0.1 / dt)
        mask[:edge] = False
        mask[n - edge :] = False
        return mask, long_mask

    def unlabeled_experiment(self, j: int, experiment: SyntheticExperiment | None = None, shuffle: str = "gap") -> tuple[MocapRecording, np.ndarray]:
        """The experiment as a passive system delivers it, with its long occlusions too: see
        :func:`make_unlabeled`."""
        exp = experiment if experiment is not None else self.experiment(j)
        rec = exp.recording.copy()
        rec.positions[exp.truth.long_occlusions] = np.nan
        return make_unlabeled(rec, np.random.default_rng([self.seed, self.index, j, 5]), self.style.ghost_rate, shuffle)


def min_jerk_outer(tau: np.ndarray, delta: np.ndarray) -> np.ndarray:
    return am.min_jerk(tau)[:, None] * delta[None, :]


def make_unlabeled(
    rec: MocapRecording, rng: np.random.Generator, ghost_rate: float = 0.25, shuffle: str = "gap"
) -> tuple[MocapRecording, np.ndarray]:
    """Unnamed trajectories: ghost markers added and identities shuffled.

    Returns the recording (markers ``Unnamed 1..K``) and ``truth_label`` ``(n_frames, K)`` int:
    the index into ``rec.marker_names`` of the marker each slot holds, ``-1`` for a ghost and
    ``-2`` for an empty slot. ``shuffle="gap"`` gives each continuous piece of trajectory a
    random free slot (as a passive tracker does); ``shuffle="frame"`` permutes slots every frame.
    Ghosts are short (30-300 ms) spurious points 3-25 cm from a body marker, still or drifting.
    """
    if shuffle not in ("gap", "frame"):
        raise ValueError(f"shuffle must be 'gap' or 'frame', got {shuffle!r}")
    n, m, _ = rec.positions.shape
    dt = 1.0 / rec.frequency
    # Pieces: (label, start, end) continuous visible runs.
    pieces: list[tuple[int, int, int, np.ndarray]] = []
    vis = rec.visible()
    for col in range(m):
        v = np.concatenate([[False], vis[:, col], [False]]).astype(int)
        starts = np.nonzero(np.diff(v) == 1)[0]
        ends = np.nonzero(np.diff(v) == -1)[0]
        for a, b in zip(starts, ends):
            pieces.append((col, a, b, rec.positions[a:b, col]))
    body = [i for i, name in enumerate(rec.marker_names) if name != "Ball"]
    n_ghosts = rng.poisson(ghost_rate * n * dt)
    for _ in range(n_ghosts):
        a = int(rng.integers(0, n - 2))
        length = int(np.clip(rng.uniform(0.03, 0.3) / dt, 2, n - a))
        anchor_col = body[int(rng.integers(0, len(body)))]
        anchor = rec.positions[a, anchor_col]
        if np.isnan(anchor).any():
            continue
        offset = rng.normal(size=3)
        offset *= rng.uniform(0.03, 0.25) / np.linalg.norm(offset)
        drift = rng.normal(0.0, 0.05, size=3) * (rng.random() < 0.5)
        t = np.arange(length)[:, None] * dt
        pts = anchor + offset + drift * t + rng.normal(0.0, 0.0007, size=(length, 3))
        pieces.append((-1, a, a + length, pts))
    # Number of slots: the most pieces visible at once.
    occupancy = np.zeros(n + 1, dtype=int)
    for _, a, b, _ in pieces:
        occupancy[a] += 1
        occupancy[b] -= 1
    k_slots = int(np.cumsum(occupancy).max())
    positions = np.full((n, k_slots, 3), np.nan)
    truth = np.full((n, k_slots), -2, dtype=int)
    free_at = np.zeros(k_slots, dtype=int)  # first frame the slot is free again
    order = sorted(range(len(pieces)), key=lambda i: pieces[i][1])
    for i in order:
        col, a, b, pts = pieces[i]
        free = np.nonzero(free_at <= a)[0]
        slot = int(free[rng.integers(0, len(free))])
        positions[a:b, slot] = pts
        truth[a:b, slot] = col
        free_at[slot] = b
    if shuffle == "frame":
        for f in range(n):
            perm = rng.permutation(k_slots)
            positions[f] = positions[f, perm]
            truth[f] = truth[f, perm]
    names = [f"Unnamed {i + 1}" for i in range(k_slots)]
    meta = dict(rec.metadata)
    meta["DESCRIPTION"] = str(meta.get("DESCRIPTION", "--")) + " (unlabelled)"
    return MocapRecording(names, positions, rec.frequency, rec.frames.copy(), rec.time.copy(), meta), truth


class SyntheticDemonstrator:
    """Entry point: ``SyntheticDemonstrator(seed).subject(i).experiment(j)`` (0-based indices)."""

    def __init__(self, seed: int = 0, n_throws: int = 8, frequency: float = FREQUENCY):
        if n_throws < 1:
            raise ValueError(f"n_throws must be at least 1, got {n_throws}")
        if not frequency > 0:
            raise ValueError(f"frequency must be positive, got {frequency}")
        self.seed, self.n_throws, self.frequency = int(seed), int(n_throws), float(frequency)

    def subject(self, i: int) -> SyntheticSubject:
        if i < 0:
            raise ValueError(f"subject index must be >= 0, got {i}")
        return SyntheticSubject(self.seed, i, self.n_throws, self.frequency)


@dataclass
class DatasetSummary:
    out_dir: str
    files: list[str] = field(default_factory=list)
    n_subjects: int = 0
    n_experiments: int = 0
    n_throws: int = 0
    seed: int = 0
    frequency: float = FREQUENCY


def generate_dataset(
    out_dir: str | Path,
    n_subjects: int = 10,
    n_experiments: int = 3,
    n_throws: int = 8,
    seed: int = 0,
    unlabeled: bool = True,
) -> DatasetSummary:
    """Write ``subject{S}_run{R}.tsv`` with ``_manually_segmented.json`` and ``_truth.npz`` beside
    it (S, R 1-based), and, with ``unlabeled``, ``unlabeled/subject{S}_run{R}.tsv`` with
    ``_labels.npz`` (slot truth, see :func:`make_unlabeled`). Also writes ``dataset.json``."""
    for name, v in (("n_subjects", n_subjects), ("n_experiments", n_experiments), ("n_throws", n_throws)):
        if v < 1:
            raise ValueError(f"{name} must be at least 1, got {v}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if unlabeled:
        (out / "unlabeled").mkdir(exist_ok=True)
    demo = SyntheticDemonstrator(seed, n_throws)
    summary = DatasetSummary(str(out), [], n_subjects, n_experiments, n_throws, seed, demo.frequency)
    styles = {}
    for i in range(n_subjects):
        subj = demo.subject(i)
        styles[f"subject{i + 1}"] = asdict(subj.style)
        for j in range(n_experiments):
            exp = subj.experiment(j)
            stem = f"subject{i + 1}_run{j + 1}"
            path = out / f"{stem}.tsv"
            write_tsv(exp.recording, path)
            write_segmentation(exp.segments, segmentation_path(path))
            exp.truth.save(out / f"{stem}_truth.npz")
            summary.files.append(path.name)
            if unlabeled:
                urec, labels = subj.unlabeled_experiment(j, exp)
                write_tsv(urec, out / "unlabeled" / f"{stem}.tsv")
                np.savez_compressed(out / "unlabeled" / f"{stem}_labels.npz", truth_label=labels,
                                    marker_names=np.array(MARKER_NAMES))
    _atomic_write_text(out / "dataset.json", json.dumps({**asdict(summary), "styles": styles}, indent=1))
    return summary


def _truth(kin: dict, time, frames, hand_speed, clean, long_gaps, release_idx, vel, landing, target,
           exact: list[Segment]) -> ExperimentTruth:
    """What the experiment really was (the hidden truth the tests and benchmarks score against)."""
    rel_rot = np.einsum("nji,njk->nik", kin["rot"], kin["hand_rot"])
    return ExperimentTruth(
        time=time, frames=frames,
        hand_position=kin["hand_centre"], hand_quaternion=am.rotation_to_quaternion(kin["hand_rot"]),
        back_position=kin["back_origin"], back_quaternion=am.rotation_to_quaternion(kin["rot"]),
        hand_position_in_back=np.einsum("nji,nj->ni", kin["rot"], kin["hand_centre"] - kin["back_origin"]),
        hand_quaternion_in_back=am.rotation_to_quaternion(rel_rot),
        shoulder=kin["shoulder"], elbow=kin["elbow"], wrist=kin["wrist"], hand_speed=hand_speed,
        clean_positions=clean, long_occlusions=long_gaps, release_frames=frames[release_idx], release_velocity=vel,
        landing_points=landing, target=target,
        segment_starts=np.array([s.start_frame for s in exact]),
        segment_ends=np.array([s.end_frame for s in exact]),
        segment_labels=[s.label for s in exact],
    )
