"""When a demonstrated grasp closes and opens, from the box's motion and the grip aperture.

The box is *carried* while its speed exceeds :data:`MOVING_SPEED` (pauses shorter than
:data:`MERGE_PAUSE_S` bridged); the carry is the moving stretch with the largest net
displacement in the searched window and must move the box at least :data:`MIN_CARRY_M`
(a bump while reaching moves it millimetres). Its start is the *lift*, its end the *place*.

* *hold aperture*: the median grip aperture during the carry;
* *close*: after the widest opening between the approach's start and the lift, the first sample
  where the aperture has come down half way to the hold aperture. Where the fingers close by
  less than :data:`MIN_APERTURE_CHANGE_M`, the lift is the close time (noted);
* *open*: after the place, the first sample where the aperture has risen half way from the
  hold aperture (or its value at the place, if wider: fingers loosen while the box is
  lowered) to its widest opening within :data:`OPEN_SEARCH_S`. Where it does not rise by
  :data:`MIN_APERTURE_CHANGE_M`, the first sample where the hand has moved
  :data:`HAND_DEPARTURE_M` away from the box (noted).

All constants are global, chosen from the physics of a grasp (a box carried over a metre; a
fingertip opening of centimetres), never per recording.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from besdrake.mocap.preprocess import velocity

#: Box speed (m/s) above which the box counts as moving.
MOVING_SPEED = 0.05
#: Pauses in the box's motion shorter than this (s) do not end a carry.
MERGE_PAUSE_S = 0.2
#: A carry moves the box at least this far (m).
MIN_CARRY_M = 0.10
#: A grip closing or opening by less than this (m) is not seen in the aperture.
MIN_APERTURE_CHANGE_M = 0.003
#: Seconds after the place searched for the opening of the grip.
OPEN_SEARCH_S = 1.5
#: The hand has left the box when their distance has grown by this much (m) over the carry's.
HAND_DEPARTURE_M = 0.02


class GraspEventError(ValueError):
    """No carry of the box, or no opening of the grip, in the searched window."""


@dataclass
class GraspEvents:
    """Row indices (into the recording) of the grasp's events, and how they were found."""

    close: int
    lift: int
    place: int
    open: int
    hold_aperture: float
    notes: list[str] = field(default_factory=list)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``(start, end)`` inclusive index runs where ``mask`` is True."""
    edges = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1))


def carry(box: np.ndarray, frequency: float, lo: int, hi: int) -> tuple[int, int]:
    """Lift and place rows of the box's longest carry in rows ``lo..hi`` (inclusive)."""
    speed = np.linalg.norm(velocity(box, frequency), axis=1)
    runs = _runs(speed[lo : hi + 1] > MOVING_SPEED)
    merged: list[list[int]] = []
    for a, b in runs:
        if merged and a - merged[-1][1] <= MERGE_PAUSE_S * frequency:
            merged[-1][1] = b
        else:
            merged.append([a, b])
    if not merged:
        raise GraspEventError("the box does not move")
    best = max(merged, key=lambda r: np.linalg.norm(box[lo + r[1]] - box[lo + r[0]]))
    moved = float(np.linalg.norm(box[lo + best[1]] - box[lo + best[0]]))
    if moved < MIN_CARRY_M:
        raise GraspEventError(f"the box moves at most {moved * 100:.1f} cm (a carry moves it {MIN_CARRY_M * 100:.0f} cm or more)")
    return lo + best[0], lo + best[1]


def grasp_events(aperture: np.ndarray, box: np.ndarray, hand: np.ndarray, frequency: float,
                 start: int, stop: int) -> GraspEvents:
    """Close, lift, place and open rows of the grasp whose approach starts at row ``start``.

    The carry is searched in rows ``start..stop`` (inclusive), the opening in the
    :data:`OPEN_SEARCH_S` after the place (up to the recording's end)."""
    lift, place = carry(box, frequency, start, stop)
    hold = float(np.median(aperture[lift : place + 1]))
    notes = []
    before = aperture[start : lift + 1]
    widest = start + int(np.argmax(before))
    if aperture[widest] - hold < MIN_APERTURE_CHANGE_M:
        close = lift
        notes.append("the fingers hardly close before the lift: close time = lift")
    else:
        level = hold + 0.5 * (aperture[widest] - hold)
        below = np.flatnonzero(aperture[widest : lift + 1] <= level)
        close = widest + int(below[0]) if len(below) else lift
    open_ = _open_row(aperture, box, hand, frequency, place, hold, lift, notes)
    return GraspEvents(int(close), int(lift), int(place), int(open_), hold, notes)


def _open_row(aperture, box, hand, frequency, place, hold, lift, notes) -> int:
    end = min(len(aperture) - 1, place + int(round(OPEN_SEARCH_S * frequency)))
    after = aperture[place : end + 1]
    widest = place + int(np.argmax(after))
    base = max(hold, float(aperture[place]))  # fingers may loosen while the box is lowered
    if aperture[widest] - base >= MIN_APERTURE_CHANGE_M:
        level = base + 0.5 * (aperture[widest] - base)
        return place + int(np.flatnonzero(after >= level)[0])
    dist = np.linalg.norm(hand - box, axis=1)
    held = float(np.median(dist[lift : place + 1]))
    away = np.flatnonzero(dist[place : end + 1] > held + HAND_DEPARTURE_M)
    if not len(away):
        raise GraspEventError(f"the grip does not open within {OPEN_SEARCH_S} s after the box is placed")
    notes.append("the fingers hardly open after the place: open time = the hand leaving the box")
    return place + int(away[0])
