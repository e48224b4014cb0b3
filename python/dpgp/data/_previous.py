"""Each vehicle's previous step (issue 34): the velocity it had one grid step earlier and the
heading it was last seen travelling in, computed where frames are made from tracks.

Definitions, for a vehicle (a track) at grid time t:

``prev_v``        its velocity at t − dt when its track was resampled there (inside the ROI or
                  not: the ROI crops frames, not the vehicle's past), else NaN in both entries.
``prev_heading``  atan2(vy, vx) of ``prev_v`` when that is at least ``heading_min_speed`` m/s;
                  slower, the vehicle's own ``prev_heading`` at t − dt (so, recursively, the
                  heading of the last step at which it moved that fast without leaving the grid);
                  NaN when it has no previous step or has not moved that fast since it appeared.

The carry-forward is why the heading is stored as a column made at framing time rather than
derived from ``prev_v`` later: a stopped vehicle's velocity direction is noise, and its last
moving heading is its orientation, but that heading may lie minutes back along the track. A slice
of frames, a shard's first frame or a time window of a streamed file does not hold that history;
the framing does (it walks every track in time order), so it writes the heading down once and
every later cut of the frames carries the right value with its rows.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .._constants import FT_TO_M
from ..exceptions import InvalidInputError, ShapeError

#: m/s: slower than this a step's direction is not a heading (as the realism checks' own floor).
HEADING_MIN_SPEED = 0.5
_NONE = np.iinfo(np.int64).min  # "no grid point before": never k - 1 of a real grid number


def check_min_speed(value: Any) -> float:
    """``heading_min_speed`` checked: a finite number of m/s, 0 or more."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = float("nan")
    if isinstance(value, (bool, np.bool_)) or not (np.isfinite(v) and v >= 0):
        raise InvalidInputError(f"heading_min_speed must be a finite number of m/s, 0 or more, got {value!r}")
    return v


def in_frame_units(min_speed: float, length_unit: str | None) -> float:
    """``min_speed`` m/s in the frames' units per second: feet when their ``length_unit`` says so,
    else metres (frames of unknown unit are taken as metres, as the framing takes them)."""
    return min_speed / FT_TO_M if length_unit == "ft" else min_speed


def own_headings(vx: np.ndarray, vy: np.ndarray, floor: float) -> np.ndarray:
    """The heading of each velocity, NaN where it is slower than ``floor`` (frames' units/s)."""
    return np.arctan2(vy, vx, out=np.full(len(vx), np.nan), where=np.hypot(vx, vy) >= floor)


def previous_steps(
    track: np.ndarray, k: np.ndarray, vx: np.ndarray, vy: np.ndarray, floor: float, carry: Any
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``prev_vx, prev_vy, prev_heading`` of grid points given track by track (each track's rows
    contiguous, its grid numbers ``k`` increasing), continuing from ``carry`` (what earlier calls
    saw of each track: :class:`LastRow` or :class:`PerTrack`), which is then updated."""
    n = len(k)
    pvx, pvy, ph = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    if n == 0:
        return pvx, pvy, ph
    block = np.flatnonzero(np.r_[True, track[1:] != track[:-1]])  # each track's first row
    b_k, b_vx, b_vy, b_h = carry.before(track[block])
    own = own_headings(vx, vy, floor)
    # cand[r]: the heading the step before r leaves (its own, else NaN), or the carried one at a
    # track's first row when the track was at k - 1 in an earlier call
    step = np.r_[False, (track[1:] == track[:-1]) & (k[1:] == k[:-1] + 1)]
    pvx[1:][step[1:]], pvy[1:][step[1:]] = vx[:-1][step[1:]], vy[:-1][step[1:]]
    cand = np.full(n, np.nan)
    cand[1:][step[1:]] = own[:-1][step[1:]]
    joined = b_k == k[block] - 1
    pvx[block[joined]], pvy[block[joined]] = b_vx[joined], b_vy[joined]
    cand[block[joined]] = b_h[joined]
    # forward fill of cand inside each run of consecutive grid points of one track
    start = np.maximum.accumulate(np.where(step, 0, np.arange(n)))
    last = np.maximum.accumulate(np.where(np.isnan(cand), -1, np.arange(n)))
    ok = last >= start
    ph[ok] = cand[last[ok]]
    end = np.r_[block[1:], n] - 1  # each track's last row
    after = np.where(np.isnan(own[end]), ph[end], own[end])
    carry.update(track[block], k[end], vx[end], vy[end], after)
    return pvx, pvy, ph


class LastRow:
    """The carry of one pass over tracks in order (batches of :func:`dpgp.make_frames`): only the
    last track seen can continue in the next batch."""

    def __init__(self) -> None:
        self.row: tuple[Any, int, float, float, float] | None = None

    def before(self, tracks: np.ndarray) -> tuple[np.ndarray, ...]:
        m = len(tracks)
        out = (np.full(m, _NONE, dtype=np.int64), np.full(m, np.nan), np.full(m, np.nan), np.full(m, np.nan))
        if self.row is not None and m and tracks[0] == self.row[0]:
            for a, value in zip(out, self.row[1:]):
                a[0] = value
        return out

    def update(self, tracks: np.ndarray, k: np.ndarray, vx: np.ndarray, vy: np.ndarray, h: np.ndarray) -> None:
        self.row = (tracks[-1], int(k[-1]), float(vx[-1]), float(vy[-1]), float(h[-1]))


class PerTrack:
    """The carry of framing in time windows (:func:`dpgp.data.shards.frame_to_shards`): each
    track's last grid point so far, by track number ``0 .. n_tracks - 1``."""

    def __init__(self, n_tracks: int) -> None:
        self.k = np.full(n_tracks, _NONE, dtype=np.int64)
        self.vx, self.vy, self.h = np.full(n_tracks, np.nan), np.full(n_tracks, np.nan), np.full(n_tracks, np.nan)

    def before(self, tracks: np.ndarray) -> tuple[np.ndarray, ...]:
        return self.k[tracks], self.vx[tracks], self.vy[tracks], self.h[tracks]

    def update(self, tracks: np.ndarray, k: np.ndarray, vx: np.ndarray, vy: np.ndarray, h: np.ndarray) -> None:
        self.k[tracks], self.vx[tracks], self.vy[tracks], self.h[tracks] = k, vx, vy, h


def previous_columns(
    ids: np.ndarray, offsets: np.ndarray, prev_v: Any, prev_heading: Any, min_speed: Any
) -> tuple[np.ndarray | None, np.ndarray | None, float | None]:
    """``Frames``' ``prev_v`` (n, 2), ``prev_heading`` (n,) and ``heading_min_speed``, checked:
    a previous velocity is finite or NaN in both entries; a heading is NaN or an angle in
    [-π, π], and NaN where there is no previous velocity. Without ``prev_heading`` each previous
    velocity's own heading (nothing to carry it from). All None without ``prev_v``."""
    if prev_v is None:
        if prev_heading is not None:
            raise InvalidInputError("prev_heading needs prev_v: a heading is carried from previous velocities")
        return None, None, None
    n = int(offsets[-1])
    if np.shape(prev_v) != (n, 2):
        raise ShapeError(f"prev_v must have shape (n, 2) like xy, ({n}, 2), got {np.shape(prev_v)}")
    if isinstance(prev_v, np.ndarray) and (prev_v.dtype.kind not in "biuf" or prev_v.dtype.itemsize == 0):
        raise ShapeError(f"prev_v must hold numbers, got dtype {prev_v.dtype}")
    pv = np.ascontiguousarray(prev_v, dtype=np.float64)
    nan = np.isnan(pv)
    bad = np.isinf(pv).any(axis=1) | (nan[:, 0] != nan[:, 1])
    if bad.any():
        raise InvalidInputError(
            f"{_where(ids, offsets, bad)}: the previous velocity {tuple(pv[bad][0].tolist())} must be finite, or NaN "
            f"in both entries where the vehicle has no previous step; {int(bad.sum())} row(s) are neither"
        )
    speed = check_min_speed(HEADING_MIN_SPEED if min_speed is None else min_speed)
    if prev_heading is None:
        return pv, own_headings(pv[:, 0], pv[:, 1], speed), speed
    if np.shape(prev_heading) != (n,):
        raise ShapeError(f"prev_heading must be one value per row ({n}), got shape {np.shape(prev_heading)}")
    if isinstance(prev_heading, np.ndarray) and (prev_heading.dtype.kind not in "biuf" or prev_heading.itemsize == 0):
        raise ShapeError(f"prev_heading must hold numbers, got dtype {prev_heading.dtype}")
    h = np.ascontiguousarray(prev_heading, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        bad = (np.abs(h) > np.pi) | np.isinf(h) | (nan[:, 0] & ~np.isnan(h))
    if bad.any():
        raise InvalidInputError(
            f"{_where(ids, offsets, bad)}: the previous heading {float(h[bad][0])!r} must be an angle in [-pi, pi] "
            f"radians, or NaN (always NaN where there is no previous velocity); {int(bad.sum())} row(s) are not"
        )
    return pv, h, speed


def _where(ids: np.ndarray, offsets: np.ndarray, bad: np.ndarray) -> str:
    """'frame i (id ...), vehicle j' of the first flagged row."""
    row = int(np.flatnonzero(bad)[0])
    k = int(np.searchsorted(offsets, row, side="right") - 1)
    ident = ids[k].item() if isinstance(ids[k], np.generic) else ids[k]
    return f"frame {k} (id {ident!r}), vehicle {row - int(offsets[k])}"
