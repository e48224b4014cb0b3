"""Tracks for frames that have none: each vehicle linked to itself in the next frame by its
velocity (issue 34: fields over heading need every vehicle's previous step).

Frame files such as the paper's NGSIM US-101 and SUMO left-turn samples hold positions and
velocities per frame but no vehicle ids. Consecutive frames are ``dt`` apart, so a vehicle at
``p`` with velocity ``v`` that has velocity ``v'`` in the next frame is at about
``p + dt (v + v') / 2`` there (the trapezoid rule: exact for constant acceleration). Each pair of
consecutive frames is matched greedily by that prediction's error, smallest first, each vehicle
used once, and no pair is linked whose error is above a gate: by default half the distance below
which 5 % of the vehicles of a frame have their nearest neighbour (two vehicles are never that
close, so a wrong link would need an error that large). Vehicles left unmatched start or end a
track. The previous velocities and headings then follow as :func:`dpgp.make_frames` gives them
(:mod:`dpgp.data._previous`).

Frames whose time step is not known are given one: the ``dt`` (on a grid from 0.02 s to 5 s, 3 %
apart) under which the vehicles' velocities best predict the next frame's positions.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..exceptions import InvalidInputError
from ._previous import HEADING_MIN_SPEED, LastRow, check_min_speed, in_frame_units, previous_steps
from .frames import Frames, as_frames
from .framing import _positive
from .provenance import FramingSummary

_DT_GRID = np.geomspace(0.02, 5.0, 190)  # 3 % apart
_DT_PAIRS = 200  # consecutive frame pairs the step is estimated on


def link_tracks(
    frames: Any,
    dt: float | None = None,
    *,
    length_unit: str | None = None,
    gate: float | None = None,
    heading_min_speed: float = HEADING_MIN_SPEED,
) -> Frames:
    """``frames`` with every vehicle linked to itself from frame to frame: track ids
    (``Frames.tracks``), previous velocities and headings (``prev_v``, ``prev_heading``), and
    frame ids that are times in seconds (the frame's number of steps from the first, times ``dt``,
    from the first id's own number of steps), as :func:`dpgp.make_frames` gives frames made from
    tracks.

    dt : seconds between consecutive frames (ids one step apart); default: the frames' own
        (``summary.dt``), else the step under which the velocities best predict the positions.
    length_unit : ``"m"`` or ``"ft"``, the unit of the positions (for ``heading_min_speed``, in
        m/s); default: the frames' own, else metres.
    gate : the largest error of a link (positions' units); default: half the distance below
        which 5 % of the vehicles' nearest neighbours in a frame lie.
    """
    frames = as_frames(frames)
    min_speed = check_min_speed(heading_min_speed)
    summary = frames.summary
    unit = length_unit if length_unit is not None else getattr(summary, "length_unit", None)
    if unit not in (None, "m", "ft"):
        raise InvalidInputError(f"length_unit must be 'm', 'ft' or None, got {length_unit!r}")
    ids = np.asarray(frames.ids, dtype=np.float64)
    if len(ids) > 1 and not np.all(np.diff(ids) > 0):
        raise InvalidInputError("frames must be in time order (increasing ids) to be linked")
    step = float(np.min(np.diff(ids))) if len(ids) > 1 else 1.0
    # k: the frame's number on the grid of steps; frames one step apart are consecutive
    k = np.round((ids - ids[0]) / step).astype(np.int64)
    pairs = np.flatnonzero(np.diff(k) == 1)
    if dt is None:
        dt = float(summary.dt) if summary is not None else _estimate_dt(frames, pairs)
    dt = _positive("dt", dt, "seconds between consecutive frames")
    gate = _default_gate(frames) if gate is None else _positive("gate", gate, "the largest error of a link")

    tracks = np.full(frames.n_points, -1, dtype=np.int64)
    next_id = 0
    off = frames.offsets
    follows = np.zeros(len(frames), dtype=bool)  # frame i is one step after frame i - 1
    follows[pairs + 1] = True
    for i in range(len(frames)):
        rows = np.arange(off[i], off[i + 1])
        if follows[i]:
            prev = np.arange(off[i - 1], off[i])
            a, b = _match(frames.xy[prev], frames.v[prev], frames.xy[rows], frames.v[rows], dt, gate)
            tracks[rows[b]] = tracks[prev[a]]
        new = rows[tracks[rows] < 0]
        tracks[new] = np.arange(next_id, next_id + len(new))
        next_id += len(new)

    row_k = np.repeat(k, frames.sizes)
    order = np.lexsort((row_k, tracks))
    floor = in_frame_units(min_speed, unit)
    pvx, pvy, ph = previous_steps(tracks[order], row_k[order], frames.v[order, 0], frames.v[order, 1], floor, LastRow())
    prev_v, prev_h = np.empty((frames.n_points, 2)), np.empty(frames.n_points)
    prev_v[order, 0], prev_v[order, 1], prev_h[order] = pvx, pvy, ph
    # ids become times in seconds on the grid of dt, as make_frames gives them: what needs
    # consecutive frames (motion learning, time order, evaluate) reads ids against dt, and frame
    # numbers one apart are not dt apart
    times = (ids[0] / step + k) * dt
    out = Frames(times, frames.offsets, frames.xy, frames.v, frames.labels, tracks, prev_v, prev_h, min_speed)
    out.summary = _summary(frames, summary, dt, unit, next_id)
    return out


def _match(
    p: np.ndarray, v: np.ndarray, q: np.ndarray, w: np.ndarray, dt: float, gate: float
) -> tuple[np.ndarray, np.ndarray]:
    """Rows of the earlier frame (``p``, ``v``) and of the later (``q``, ``w``) linked: greedy by
    the trapezoid prediction's error, smallest first, each row once, errors below ``gate``."""
    err = _link_errors(p, v, q, w, dt)
    a_all, b_all = np.nonzero(err < gate)
    keep = np.argsort(err[a_all, b_all], kind="stable")
    used_a, used_b = np.zeros(len(p), bool), np.zeros(len(q), bool)
    a_out, b_out = [], []
    for a, b in zip(a_all[keep], b_all[keep]):
        if not used_a[a] and not used_b[b]:
            used_a[a] = used_b[b] = True
            a_out.append(a)
            b_out.append(b)
    return np.asarray(a_out, dtype=np.int64), np.asarray(b_out, dtype=np.int64)


def _link_errors(p: np.ndarray, v: np.ndarray, q: np.ndarray, w: np.ndarray, dt: float) -> np.ndarray:
    """(len(p), len(q)): how far each later vehicle lies from where each earlier one would be had
    it become that vehicle, ``p + dt (v + w) / 2`` (the trapezoid rule)."""
    pred = p[:, None, :] + 0.5 * dt * (v[:, None, :] + w[None, :, :])
    return np.hypot(*(pred - q[None, :, :]).transpose(2, 0, 1))


def _nearest_errors(frames: Frames, pairs: np.ndarray, dt: float) -> np.ndarray:
    """Each moving vehicle's error under the best link it could have: the smallest trapezoid
    prediction error over the vehicles of the next frame, over ``pairs``. Standing vehicles are
    left out: they are where they were under any ``dt``."""
    off, out = frames.offsets, []
    for i in pairs:
        p, v = frames.xy[off[i] : off[i + 1]], frames.v[off[i] : off[i + 1]]
        q, w = frames.xy[off[i + 1] : off[i + 2]], frames.v[off[i + 1] : off[i + 2]]
        d = _link_errors(p, v, q, w, dt).min(axis=1)
        out.append(d[np.hypot(v[:, 0], v[:, 1]) > 0])
    return np.concatenate(out) if out else np.empty(0)


def _estimate_dt(frames: Frames, pairs: np.ndarray) -> float:
    if len(pairs) == 0:
        raise InvalidInputError("no two frames are one step apart: there is nothing to link; give dt")
    sample = pairs[np.unique(np.linspace(0, len(pairs) - 1, min(_DT_PAIRS, len(pairs))).astype(np.int64))]
    errors = [_nearest_errors(frames, sample, dt) for dt in _DT_GRID]
    if not len(errors[0]):
        raise InvalidInputError("no vehicle moves between consecutive frames: the time step cannot be told; give dt")
    return float(_DT_GRID[int(np.argmin([np.median(e) for e in errors]))])


def _default_gate(frames: Frames) -> float:
    off, nearest = frames.offsets, []
    for i in np.flatnonzero(frames.sizes > 1):
        p = frames.xy[off[i] : off[i + 1]]
        d = np.hypot(*(p[:, None, :] - p[None, :, :]).transpose(2, 0, 1))
        np.fill_diagonal(d, np.inf)
        nearest.append(d.min(axis=1))
    if not nearest:
        return float("inf")  # one vehicle a frame: whatever is there is the same vehicle
    spacing = float(np.quantile(np.concatenate(nearest), 0.05))
    return 0.5 * spacing if spacing > 0 else float("inf")


def _summary(frames: Frames, summary: Any, dt: float, unit: str | None, n_tracks: int) -> FramingSummary:
    if summary is not None:
        return dataclasses.replace(summary, length_unit=unit)
    n = frames.n_points
    return FramingSummary(
        dt=dt, max_gap=dt, roi=None, units=None, velocity="columns", smoothing=None, n_rows=n,
        n_tracks=n_tracks, n_segments=n_tracks, n_gaps=0, n_gap_times=0, n_segments_between_grid_times=0,
        n_rows_between_grid_times=0, n_single_sample_segments=0, n_unsmoothed_segments=0, n_resampled=n,
        n_outside_roi=0, n_points=n, n_frames=len(frames), n_empty_frames=0, n_scenes=1, length_unit=unit,
    )  # fmt: skip


__all__ = ["link_tracks"]
