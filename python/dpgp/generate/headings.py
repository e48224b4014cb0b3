"""Previous headings for generation through fields over heading (issue 34, docs/heading.md).

A field over heading gives a vehicle's velocity at its position *and* the heading of its
previous step. The core keeps that heading as a rollout runs (the last velocity at least
``heading_min_speed`` fast, as :func:`dpgp.make_frames` carries it through stops); what it needs
from here is each vehicle's heading at the start:

- a recorded vehicle: its frame's ``prev_heading``; at a first appearance (none recorded) the
  heading of its own velocity when that is fast enough: the direction it is seen travelling, which
  for generation is better than none (a field averaged over heading is the mean of every
  direction through the point: near zero between opposite lanes);
- a vehicle with neither: ``NaN``, and the field averaged over heading answers for it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..data._previous import HEADING_MIN_SPEED, in_frame_units, own_headings


def heading_speed(fit: Any) -> float:
    """The speed, in the frames' units per second, from which a velocity gives a heading: the one
    the training frames were framed with (m/s, so 1.64 ft/s for frames in feet), else
    :data:`~dpgp.data._previous.HEADING_MIN_SPEED`."""
    speed = getattr(fit.frames, "heading_min_speed", None)
    summary = getattr(fit.frames, "summary", None)
    mps = float(speed) if speed is not None else HEADING_MIN_SPEED
    return in_frame_units(mps, getattr(summary, "length_unit", None))


def start_headings(v: np.ndarray | None, prev_heading: np.ndarray | None, min_speed: float, n: int) -> np.ndarray:
    """(n,): the recorded previous headings, else the heading of the own velocity ``v`` when at
    least ``min_speed`` fast, else ``NaN``."""
    h = np.full(n, np.nan) if prev_heading is None else np.asarray(prev_heading, dtype=np.float64).copy()
    if v is not None and len(v):
        own = own_headings(np.asarray(v[:, 0], np.float64), np.asarray(v[:, 1], np.float64), min_speed)
        h = np.where(np.isnan(h), own, h)
    return h


def for_core(fit: Any, h: np.ndarray | None) -> tuple[np.ndarray, float] | None:
    """What the core's rollouts take: ``(headings, min speed)`` for a fit over heading, else
    ``None`` (a field over position ignores headings)."""
    if not getattr(fit, "headed", False) or h is None:
        return None
    return np.ascontiguousarray(h, dtype=np.float64), heading_speed(fit)


def carried(velocities: np.ndarray, start: np.ndarray, min_speed: float) -> np.ndarray:
    """(l,): each vehicle's heading after a rollout's ``velocities`` (steps + 1, l, 2): that of its
    last velocity at least ``min_speed`` fast, else ``start``'s."""
    h = np.asarray(start, dtype=np.float64).copy()
    for v in velocities:
        own = own_headings(v[:, 0], v[:, 1], max(min_speed, np.finfo(float).tiny))
        h = np.where(np.isnan(own), h, own)
    return h


__all__ = ["heading_speed", "start_headings", "for_core", "carried"]
