"""Free speeds learned from a recording (issue 20; dpgp.generate.free_speeds)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

import dpgp
from dpgp.generate.free_speeds import MIN_MOVING, learn_free_speeds

VEHICLES = SimpleNamespace(agents="vehicles")


def _frames(seed: int = 0, n: int = 3000) -> dpgp.Frames:
    """Vehicle observations scattered over a 20 m square, headings in all directions, speeds
    0 to 15 (a tenth standing), one per frame."""
    rng = np.random.default_rng(seed)
    angle = rng.uniform(-np.pi, np.pi, n)
    speed = np.where(rng.random(n) < 0.1, 0.0, rng.uniform(0.0, 15.0, n))
    df = pd.DataFrame({
        "track": np.arange(n), "t": np.arange(n) * 0.5, "x": rng.uniform(0, 20, n), "y": rng.uniform(0, 20, n),
        "vx": speed * np.cos(angle), "vy": speed * np.sin(angle),
    })  # fmt: skip
    return dpgp.make_frames(df, dt=0.5)


def test_free_speeds_are_the_85th_percentile_of_the_moving_vehicles_by_cell_and_heading():
    frames = _frames()
    free = learn_free_speeds(SimpleNamespace(frames=frames), 5.0, VEHICLES)
    assert free is not None and free.speeds.shape[2] == 8
    # an independent count: every cell and sector by plain loops
    xy, v = np.asarray(frames.xy), np.asarray(frames.v)
    speed = np.hypot(*v.T)
    moving = speed >= 0.05 * np.quantile(speed, 0.9)
    angle = np.degrees(np.arctan2(v[:, 1], v[:, 0]))
    checked = 0
    for ix in range(free.speeds.shape[0]):
        for iy in range(free.speeds.shape[1]):
            lo = free.origin + 5.0 * np.array([ix, iy])
            inside = np.all((xy >= lo) & (xy < lo + 5.0), axis=1) & moving
            for s in range(8):
                off = (angle - 45.0 * s + 180.0) % 360.0 - 180.0  # within ±22.5° of the sector's centre
                mine = speed[inside & (np.abs(off) < 22.5)]
                got = free.speeds[ix, iy, s]
                if len(mine) >= MIN_MOVING:
                    assert got == pytest.approx(np.quantile(mine, 0.85)), (ix, iy, s)
                    checked += 1
                else:
                    assert np.isnan(got), (ix, iy, s, len(mine))
    assert checked >= 100
    # the lookup the core makes, from Python
    p = np.array([[7.0, 12.0]])
    ij = np.floor((p[0] - free.origin) / 5.0).astype(int)
    np.testing.assert_equal(free.at(p, np.array([[0.0, -2.0]]))[0], free.speeds[ij[0], ij[1], 6])
    assert np.isnan(free.at(np.array([[-50.0, 0.0]]), np.array([[1.0, 0.0]]))[0])


def test_pedestrians_have_no_free_speeds():
    assert learn_free_speeds(SimpleNamespace(frames=_frames(n=200)), 5.0, SimpleNamespace(agents="pedestrians")) is None
