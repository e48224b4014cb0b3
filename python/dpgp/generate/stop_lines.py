"""Red signals' stop lines, learned from the recording (issue 20; docs/dynamics.md).

The fitted velocity fields cannot say "stand" where a queue stands: at a red light's queue each
pattern's mean mixes the vehicles standing there with those that discharge there at green (on the
SUMO junction 0.1–4.7 m/s where 400–700 vehicle-frames stood), and a generated vehicle crept
through the red. A long scenario by signal stage therefore tells its vehicles where to stop, as
the recording shows it:

1. a *queue front* is a standing vehicle (slower than 5% of the 90th percentile speed) with no
   vehicle ahead within twice the queues' spacing in its lane's corridor (the median distance,
   centre to centre, from a standing vehicle to the standing one ahead of it), its heading the
   direction it last moved in;
2. the fronts cluster where the stop lines are: per lane (cells of the lane's width, one heading
   sector in eight), merged along the queues' spacing and across a corridor; a cluster with at least
   :data:`MIN_FRONTS` fronts and a twentieth of the largest one's is a stop line, at its fronts'
   median position, heading their mean heading;
3. a line is *red* in a phase where the vehicles that reach it mostly stop there: of the track
   steps that cross it (passes) and the vehicles that become its queue's front (arrivals that
   stop), in that phase's frames, at least :data:`MIN_STOPS` stop and fewer than half pass
   (counted with one of each added).

The core treats a red line as a standing vehicle for the vehicles of its approach (``motion.rs``:
``Stop``); a vehicle too close to stop clears it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..data.timeorder import time_order
from ..gp.fitted import FittedPatterns
from .motion import consecutive_pairs

#: a stop line needs at least this many queue-front vehicle-frames (and 1/20 of the largest line's)
MIN_FRONTS = 10
#: a line is red in a phase only where at least this many vehicles stopped at it (on Peachtree's
#: small window, one vehicle that stopped and none that passed made a line red for a phase)
MIN_STOPS = 3
_SHARE_OF_LARGEST = 0.05
STAND_SHARE = 0.05  # standing: slower than this share of the 90th percentile speed
SECTORS = 8  # heading sectors (the core's free_speed::SECTORS)
_SAME_WAY = 0.5  # cos 60°: the heading within which a vehicle belongs to a line's approach


@dataclass(frozen=True, eq=False)
class StopLines:
    """Stop lines ``at`` (S, 2) for traffic heading along ``heading`` (S, 2, unit), ``red`` (P, S)
    in which phases each is red; ``passes`` and ``stops`` (P, S) the evidence: the recorded
    vehicles that crossed each line and that became its queue's front, by phase."""

    at: np.ndarray
    heading: np.ndarray
    red: np.ndarray
    passes: np.ndarray
    stops: np.ndarray

    def __len__(self) -> int:
        return len(self.at)

    def in_force(self, phase: int) -> list[tuple[float, float, float, float]]:
        """The red lines in ``phase`` as the core takes them: ``(x, y, heading x, heading y)``."""
        on = np.flatnonzero(self.red[phase]) if len(self.at) else np.zeros(0, dtype=np.int64)
        at, e = self.at.astype(float), self.heading.astype(float)
        return [(float(at[i, 0]), float(at[i, 1]), float(e[i, 0]), float(e[i, 1])) for i in on]

    def signal_groups(self) -> np.ndarray:
        """Each phase's signal phase: phases with the same red lines share one (numbered in order
        of first appearance). On the SUMO junction its 4 stages pair into the signal's 2 phases."""
        keys = [tuple(np.flatnonzero(row)) for row in self.red]
        ids = {k: i for i, k in enumerate(dict.fromkeys(keys))}
        return np.array([ids[k] for k in keys], dtype=np.int64)

    def summary(self) -> str:
        lines = [f"{len(self)} stop lines; signal phases by their red lines: {self.signal_groups().tolist()}"]
        for i in range(len(self)):
            red = np.flatnonzero(self.red[:, i]).tolist()
            lines.append(
                f"  at ({self.at[i, 0]:.1f}, {self.at[i, 1]:.1f}) heading ({self.heading[i, 0]:.2f}, "
                f"{self.heading[i, 1]:.2f}): red in phases {red}; passed {self.passes[:, i].tolist()}, "
                f"stopped {self.stops[:, i].tolist()}"
            )
        return "\n".join(lines)


def heading_sector(direction: np.ndarray) -> np.ndarray:
    """The heading sector (of :data:`SECTORS`; sector ``i`` centred on the angle ``i · 2π / 8``)
    of each direction (n, 2)."""
    return np.rint(np.arctan2(direction[:, 1], direction[:, 0]) / (2 * np.pi / SECTORS)).astype(np.int64) % SECTORS


def _empty(n_phases: int) -> StopLines:
    z = np.zeros((0, 2))
    return StopLines(
        z, z.copy(), np.zeros((n_phases, 0), bool), np.zeros((n_phases, 0), np.int64), np.zeros((n_phases, 0), np.int64)
    )


def _last_heading(v: np.ndarray, moving: np.ndarray, key: np.ndarray, new_track: np.ndarray) -> np.ndarray:
    """Each row's heading (unit; NaN before its track first moved): the direction of the track's
    latest moving row, rows in track order ``key``."""
    n = len(key)
    idx = np.where(moving[key], np.arange(n), -1)
    start = np.maximum.accumulate(np.where(new_track, np.arange(n), 0))
    last = np.maximum.accumulate(idx)
    ok = last >= start  # moved since its track began
    head = np.full((len(v), 2), np.nan)
    src = key[last[ok]]
    head[key[ok]] = v[src] / np.hypot(*v[src].T)[:, None]
    return head


def _ahead(
    xy: np.ndarray, head: np.ndarray, standing: np.ndarray, rows: np.ndarray, lateral: float
) -> tuple[np.ndarray, np.ndarray]:
    """For each standing row with a heading: the distance to the nearest vehicle of its frame ahead
    in its corridor of half-width ``lateral`` (inf: none; NaN for other rows), and whether that
    vehicle stands too."""
    near = np.full(len(xy), np.nan)
    near_stands = np.zeros(len(xy), dtype=bool)
    cand = np.flatnonzero(standing & np.isfinite(head[:, 0]))
    order = np.argsort(rows, kind="stable")
    bounds = np.searchsorted(rows[order], np.arange(rows.max() + 2)) if len(rows) else np.zeros(1, np.int64)
    for i in cand:
        mates = order[bounds[rows[i]] : bounds[rows[i] + 1]]
        d = xy[mates] - xy[i]
        along = d @ head[i]
        side = np.abs(d[:, 0] * head[i, 1] - d[:, 1] * head[i, 0])
        ahead = np.flatnonzero((along > 1e-9) & (side <= lateral))
        if len(ahead):
            j = ahead[np.argmin(along[ahead])]
            near[i], near_stands[i] = along[j], standing[mates[j]]
        else:
            near[i] = np.inf
    return near, near_stands


def _cluster(xy: np.ndarray, head: np.ndarray, fronts: np.ndarray, spacing: float, lateral: float) -> list[np.ndarray]:
    """The fronts grouped by lane cell and heading sector, cells merged (largest first) into a line
    within the queues' ``spacing`` along and a corridor across."""
    f = np.flatnonzero(fronts)
    sector = heading_sector(head[f])
    cell = np.floor(xy[f] / (2 * lateral)).astype(np.int64)
    keys, inverse = np.unique(np.c_[cell, sector], axis=0, return_inverse=True)
    inverse = inverse.ravel()
    groups: list[tuple[int, np.ndarray, list[np.ndarray]]] = []  # sector, centre, members
    for c in np.argsort(-np.bincount(inverse), kind="stable"):
        members = f[inverse == c]
        centre = xy[members].mean(axis=0)
        s = int(keys[c, 2])
        e = np.array([np.cos(s * 2 * np.pi / SECTORS), np.sin(s * 2 * np.pi / SECTORS)])
        for sec, at, parts in groups:
            d = at - centre
            if sec == s and abs(d @ e) < spacing and abs(d[0] * e[1] - d[1] * e[0]) < lateral:
                parts.append(members)
                break
        else:
            groups.append((s, centre, [members]))
    return [np.concatenate(parts) for _, _, parts in groups]


def learn_stop_lines(fit: FittedPatterns, labels: np.ndarray, n_phases: int, motion: Any) -> StopLines:
    """The :class:`StopLines` of the training frames whose phases are ``labels`` (one per frame, of
    ``n_phases``), for vehicles following by ``motion``'s IDM (a
    :class:`dpgp.generate.motion.MotionModel`); none for pedestrians or frames without track ids."""
    frames = fit.frames
    jam, lateral = float(motion.jam), float(motion.lateral)
    if motion.agents != "vehicles" or frames.tracks is None or not (jam > 0 and lateral > 0) or not len(frames.xy):
        return _empty(n_phases)
    xy, v = np.asarray(frames.xy, dtype=np.float64), np.asarray(frames.v, dtype=np.float64)
    rows = np.asarray(frames.frame_of_row)
    order = time_order(frames)
    speed = np.hypot(*v.T)
    standing = speed < STAND_SHARE * np.quantile(speed, 0.9)
    # rows by recording and track, in time order (a track id may recur in another recording)
    key = np.lexsort((order.time[rows], frames.tracks, order.scene[rows]))
    tracks, scenes = np.asarray(frames.tracks)[key], order.scene[rows][key]
    new_track = np.r_[True, (tracks[1:] != tracks[:-1]) | (scenes[1:] != scenes[:-1])]
    head = _last_heading(v, ~standing, key, new_track)
    near, near_stands = _ahead(xy, head, standing, rows, lateral)
    # the recorded queues' spacing (centre to centre, standing behind standing): the fitted jam
    # distance is a car-following fit and may be far from it
    queued = near_stands & np.isfinite(near)
    spacing = float(np.median(near[queued])) if queued.any() else jam
    front = np.isfinite(head[:, 0]) & standing & ~(near <= 2 * spacing)
    groups = [g for g in _cluster(xy, head, front, spacing, lateral) if len(g) >= MIN_FRONTS]
    if groups:
        largest = max(len(g) for g in groups)
        groups = [g for g in groups if len(g) >= _SHARE_OF_LARGEST * largest]
    if not groups:
        return _empty(n_phases)
    phase = np.asarray(labels)[rows]
    # the track steps, and the rows where a vehicle became its queue's front
    a, b = consecutive_pairs(frames, order.dt)
    arrived = front.copy()
    arrived[b] &= ~front[a]
    at = np.array([np.median(xy[g], axis=0) for g in groups])
    heading = np.array([np.nanmean(head[g], axis=0) for g in groups])
    heading /= np.hypot(*heading.T)[:, None]
    passes = np.zeros((n_phases, len(groups)), dtype=np.int64)
    stops = np.zeros_like(passes)
    for i, g in enumerate(groups):
        e, n = heading[i], np.array([-heading[i, 1], heading[i, 0]])
        before, after = (xy[a] - at[i]) @ e, (xy[b] - at[i]) @ e
        crossed = (before < 0) & (after >= 0) & (np.abs((xy[a] - at[i]) @ n) <= lateral)
        crossed &= np.nan_to_num(head[a] @ e) >= _SAME_WAY
        passes[:, i] = np.bincount(phase[a[crossed]], minlength=n_phases)
        stops[:, i] = np.bincount(phase[g[arrived[g]]], minlength=n_phases)
    return StopLines(at, heading, red_in(passes, stops), passes, stops)


def red_in(passes: np.ndarray, stops: np.ndarray) -> np.ndarray:
    """Where a line is red: at least :data:`MIN_STOPS` vehicles stopped there, and fewer than half
    of those that reached it passed (counted with one of each added)."""
    passes, stops = np.asarray(passes), np.asarray(stops)
    return (stops >= MIN_STOPS) & ((passes + 1) / (passes + stops + 2) < 0.5)


__all__ = ["StopLines", "learn_stop_lines", "red_in", "MIN_FRONTS", "MIN_STOPS"]
