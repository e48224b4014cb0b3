"""Time order of frames (issue 20): which frame follows which.

Frames from :func:`dpgp.make_frames` have ids that are grid times in seconds, or ``(scene, time)``
pairs when the tracks have a ``scene`` column (a model file stores those pairs as their text,
``"(3, 12.5)"``, which is read back here). Two frames are *consecutive* when they belong to one
scene and their times differ by the grid step ``dt``; a gap (no frame at ``t + dt``) ends a run
and starts another, as a scene's exit and entry. Frames whose ids are not times have no order:
everything that needs one raises :class:`~dpgp.exceptions.UnorderedFramesError`."""

from __future__ import annotations

import ast
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..exceptions import UnorderedFramesError

_HOW = (
    "frames made by dpgp.make_frames from tracks with a time column have them (ids that are grid "
    "times, or (scene, time) pairs)"
)


@dataclass(frozen=True, eq=False)
class TimeOrder:
    """The recording order of a set of frames.

    ``scene``: each frame's scene code (0 when there is one scene); ``time``: its time in seconds;
    ``dt``: the grid step; ``next`` / ``prev``: the index of the consecutive frame after / before
    it, ``-1`` where there is none (a scene's last / first frame, or a gap)."""

    scene: np.ndarray
    time: np.ndarray
    dt: float
    next: np.ndarray
    prev: np.ndarray

    def __len__(self) -> int:
        return len(self.time)

    def sequences(self) -> list[np.ndarray]:
        """Frame indices of each unbroken run of consecutive frames, in time order."""
        starts = np.flatnonzero(self.prev < 0)
        out = []
        for s in starts:
            seq = [int(s)]
            while self.next[seq[-1]] >= 0:
                seq.append(int(self.next[seq[-1]]))
            out.append(np.asarray(seq, dtype=np.int64))
        return out


def _parse_id(x: Any) -> tuple[Any, float]:
    """``(scene, time)`` of one frame id; ``ValueError`` when it is not a time."""
    if isinstance(x, str):
        try:
            x = ast.literal_eval(x.strip())  # literals only: "(3, 12.5)", "('a', 1.0)", "12.5"
        except (ValueError, SyntaxError):
            raise ValueError(x) from None
    if isinstance(x, (tuple, list)) and len(x) == 2:
        scene, t = x
    else:
        scene, t = 0, x
    if isinstance(t, (bool, np.bool_)) or not isinstance(t, (int, float, np.integer, np.floating)):
        raise ValueError(x)
    return scene, float(t)


def frame_times(ids: Any) -> tuple[np.ndarray, np.ndarray]:
    """Scene codes and times (seconds) of frame ids; :class:`UnorderedFramesError` if they are not times."""
    ids = np.asarray(ids)
    if ids.ndim != 1:
        ids = np.asarray(list(map(tuple, ids)) if ids.ndim == 2 else [], dtype=object)
    if ids.dtype.kind in "iuf":
        times = ids.astype(np.float64)
        scenes = np.zeros(len(ids), dtype=np.int64)
    else:
        try:
            pairs = [_parse_id(x) for x in ids.tolist()]
        except ValueError as e:
            raise UnorderedFramesError(
                f"frame id {e.args[0]!r} is not a time: these frames have no time order; {_HOW}"
            ) from None
        names = [p[0] for p in pairs]
        try:
            _, scenes = np.unique(np.asarray(names), return_inverse=True)
        except TypeError:  # scene names of mixed kinds
            lookup = {n: i for i, n in enumerate(dict.fromkeys(map(repr, names)))}
            scenes = np.array([lookup[repr(n)] for n in names])
        times = np.array([p[1] for p in pairs], dtype=np.float64)
        scenes = np.asarray(scenes, dtype=np.int64).reshape(-1)
    if len(times) and not np.all(np.isfinite(times)):
        raise UnorderedFramesError(f"frame times must be finite numbers; {_HOW}")
    return scenes, times


def time_order(frames_or_ids: Any, dt: float | None = None) -> TimeOrder:
    """The :class:`TimeOrder` of frames (or of their ids).

    ``dt``: the grid step in seconds; ``None`` takes the smallest positive time difference within
    a scene (the step :func:`dpgp.make_frames` used). Two frames of one scene at the same time are
    an :class:`UnorderedFramesError`."""
    ids = getattr(frames_or_ids, "ids", frames_or_ids)
    if dt is None:  # the step make_frames used, when the frames say it
        dt = getattr(getattr(frames_or_ids, "summary", None), "dt", None)
    scenes, times = frame_times(ids)
    n = len(times)
    order = np.lexsort((times, scenes))
    s, t = scenes[order], times[order]
    same = s[1:] == s[:-1]
    gaps = np.diff(t)[same]
    if np.any(gaps <= 0):
        k = int(np.flatnonzero(same & (np.diff(t) <= 0))[0])
        raise UnorderedFramesError(
            f"two frames of one scene share the time {t[k]:g} s; frames of several recordings need "
            "(scene, time) ids (give the tracks a 'scene' column)"
        )
    if dt is None:
        dt = float(gaps.min()) if len(gaps) else 1.0
    elif not (isinstance(dt, (int, float, np.integer, np.floating)) and np.isfinite(dt) and dt > 0):
        raise UnorderedFramesError(f"dt must be a positive number of seconds, got {dt!r}")
    dt = float(dt)
    step = np.zeros(max(n - 1, 0), dtype=bool)
    step[same] = np.abs(gaps - dt) <= 1e-6 * max(1.0, dt)
    nxt = np.full(n, -1, dtype=np.int64)
    prv = np.full(n, -1, dtype=np.int64)
    a, b = order[:-1][step], order[1:][step]
    nxt[a], prv[b] = b, a
    return TimeOrder(scenes, times, dt, nxt, prv)


__all__ = ["TimeOrder", "frame_times", "time_order"]
