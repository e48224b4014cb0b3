"""A two-way road's tracks for the tests of fields over heading (issue 34)."""

from __future__ import annotations

import numpy as np
import pandas as pd


def two_way_road(n_vehicles: int = 24, seed: int = 0, gap: float = 3.0, vy_noise: float = 0.1) -> pd.DataFrame:
    """Opposite lanes ``gap`` m apart: eastbound at y = 0, westbound at y = gap, one vehicle
    entering every 2 s on alternate lanes, tracks sampled at 1 s (lateral velocities noise of
    spread ``vy_noise``)."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n_vehicles):
        east = i % 2 == 0
        speed = 10.0 + rng.normal(0, 0.5)
        for t in range(2 * i, 2 * i + 8):
            s = speed * (t - 2 * i)
            x = s if east else 70.0 - s
            rows.append((i, float(t), x, 0.0 if east else gap, speed if east else -speed, rng.normal(0, vy_noise)))
    return pd.DataFrame(rows, columns=["track", "t", "x", "y", "vx", "vy"])
