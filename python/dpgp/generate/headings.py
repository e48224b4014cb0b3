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

from .._validate import real_number
from ..data._previous import HEADING_MIN_SPEED, in_frame_units, own_headings
from ..exceptions import InvalidInputError


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


#: The share of recorded moving steps whose curvature the learned turning limit allows.
CURVATURE_QUANTILE = 99.0


def recorded_curvature(fit: Any, quantile: float = CURVATURE_QUANTILE) -> float:
    """The turning limit the training frames show (per unit of their length): the ``quantile``-th
    percentile of ``|Δheading| / (speed · dt)`` over the rows whose previous heading is known
    and whose velocity is at least the heading speed fast (``Δheading``: from the previous heading
    to the velocity's, wrapped to ``[0, π]``; ``dt`` the frames' time step). A minimum turning radius
    of ``1 / κ``: vehicles turn with the path they drive. Kept in the fit's cache (for its frames)
    at the default quantile."""
    frames = fit.frames
    cached = fit.cache.get("max_curvature")
    if quantile == CURVATURE_QUANTILE and cached is not None and cached[0] is frames:
        return float(cached[1])
    h = frames.prev_heading
    speed = np.hypot(frames.v[:, 0], frames.v[:, 1])
    rows = np.isfinite(h) & (speed >= max(heading_speed(fit), np.finfo(float).tiny))
    if not rows.any():
        raise InvalidInputError(
            "the training frames hold no moving vehicle with a previous heading to learn a turning "
            "limit from: pass max_curvature as a number (per unit length)"
        )
    turn = np.abs(np.angle(np.exp(1j * (np.arctan2(frames.v[rows, 1], frames.v[rows, 0]) - h[rows]))))
    kappa = float(np.percentile(turn / (speed[rows] * fit.dt), quantile))
    if quantile == CURVATURE_QUANTILE:
        fit.cache["max_curvature"] = (frames, kappa)
    return kappa


def check_max_curvature(value: Any, fit: Any, dynamics: str) -> float | None:
    """``max_curvature`` checked: ``None`` (the pure field), ``"recorded"``
    (:func:`recorded_curvature`) or a positive number per unit length; a limit needs the pure
    field (``dynamics="field"``) of a fit over heading."""
    if value is None:
        return None
    if not getattr(fit, "headed", False):
        raise InvalidInputError(
            "max_curvature limits the turning of vehicles in fields over heading; this model's fields "
            "are over position (fit with inputs='position+heading')"
        )
    if dynamics != "field":
        raise InvalidInputError(
            f"max_curvature is a limit of the pure field (dynamics='field'), not of {dynamics!r} dynamics, "
            "whose drivers steer with their own time constant"
        )
    if isinstance(value, str):
        if value != "recorded":
            raise InvalidInputError(f"max_curvature must be 'recorded', a positive number or None, got {value!r}")
        return recorded_curvature(fit)
    k = real_number("max_curvature", value)
    if not (np.isfinite(k) and k > 0):
        raise InvalidInputError(f"max_curvature must be a positive number per unit length, got {value!r}")
    return k


__all__ = [
    "heading_speed",
    "start_headings",
    "for_core",
    "carried",
    "recorded_curvature",
    "check_max_curvature",
    "CURVATURE_QUANTILE",
]
