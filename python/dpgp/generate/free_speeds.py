"""Free speeds, learned from the recording (issue 20; docs/dynamics.md): how fast the recorded
vehicles drove where they moved, per lane cell and heading sector (eight), as the 85th
percentile of the moving vehicles' speeds there (the traffic engineer's free-flow speed; a cell
and sector with fewer than :data:`MIN_MOVING` moving vehicle-frames has none). Long scenarios by
phase raise each field's mean to it where the mean is slower (the core's ``AtFreeSpeed``): the
fields' means are slow where vehicles queue and start, and where a lane runs beside the opposite
one, and a driver following that mean crawled; with the queues made by the stop lines
(:mod:`.stop_lines`) and the car-following rule, a driver's wish is the free speed and the field
gives the direction."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..gp.fitted import FittedPatterns
from .stop_lines import SECTORS, STAND_SHARE, heading_sector

MIN_MOVING = 10  # moving vehicle-frames a cell and heading need for a free speed
QUANTILE = 0.85


@dataclass(frozen=True, eq=False)
class FreeSpeeds:
    """Free speeds ``speeds`` (nx, ny, 8) on square cells of side ``cell`` from ``origin``, per
    heading sector (sector ``i`` centred on the angle ``i · 2π / 8``); NaN where none."""

    origin: np.ndarray
    cell: float
    speeds: np.ndarray

    def core(self) -> tuple[float, float, float, np.ndarray]:
        """What the core takes: ``(origin x, origin y, cell, speeds)``."""
        return float(self.origin[0]), float(self.origin[1]), float(self.cell), np.ascontiguousarray(self.speeds)

    def at(self, xy: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """The free speed at each point of ``xy`` (n, 2) heading along ``direction`` (n, 2);
        NaN where none was recorded."""
        xy, direction = np.atleast_2d(xy), np.atleast_2d(direction)
        ij = np.floor((xy - self.origin) / self.cell).astype(np.int64)
        sector = heading_sector(direction)
        n = np.array(self.speeds.shape[:2])
        ok = np.all((ij >= 0) & (ij < n), axis=1)
        out = np.full(len(xy), np.nan)
        out[ok] = self.speeds[ij[ok, 0], ij[ok, 1], sector[ok]]
        return out


def learn_free_speeds(fit: FittedPatterns, cell: float, motion: Any) -> FreeSpeeds | None:
    """The :class:`FreeSpeeds` of the training frames on cells of side ``cell`` (a lane's width);
    ``None`` for pedestrians (``motion.agents``), whose fields are their speeds."""
    if motion.agents != "vehicles" or not len(fit.frames.xy):
        return None
    xy, v = np.asarray(fit.frames.xy, dtype=np.float64), np.asarray(fit.frames.v, dtype=np.float64)
    speed = np.hypot(*v.T)
    moving = speed >= STAND_SHARE * np.quantile(speed, 0.9)
    origin = xy.min(axis=0) - cell
    ij = np.floor((xy[moving] - origin) / cell).astype(np.int64)
    shape = (*(ij.max(axis=0) + 2), SECTORS) if len(ij) else (1, 1, SECTORS)
    flat = np.ravel_multi_index((ij[:, 0], ij[:, 1], heading_sector(v[moving])), shape)
    speeds = np.full(int(np.prod(shape)), np.nan)
    order = np.argsort(flat, kind="stable")
    keys, starts, counts = np.unique(flat[order], return_index=True, return_counts=True)
    moved = speed[moving][order]
    for key, a, c in zip(keys, starts, counts):
        if c >= MIN_MOVING:
            speeds[key] = np.quantile(moved[a : a + c], QUANTILE)
    return FreeSpeeds(origin, float(cell), speeds.reshape(shape))


__all__ = ["FreeSpeeds", "learn_free_speeds", "MIN_MOVING", "QUANTILE"]
