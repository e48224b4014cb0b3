"""Criticality measures (issue 35) against a plain numpy/scipy oracle: overlap by corner-in-polygon
and edge crossings, time to collision by scanning time and bisecting, the gap as a small convex
program (scipy), post-encroachment time in closed form for straight constant-velocity paths."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.optimize import minimize

import dpgp
from dpgp.exceptions import InvalidInputError
from dpgp.generate.criticality import Criticality, RecordedScene, criticality, recorded_scenes

SIZE = (4.0, 1.8)


def corners(c, h, size=SIZE) -> np.ndarray:
    u, n = np.array([math.cos(h), math.sin(h)]), np.array([-math.sin(h), math.cos(h)])
    hl, hw = size[0] / 2, size[1] / 2
    return np.array([c + i * hl * u + j * hw * n for i, j in ((1, 1), (-1, 1), (-1, -1), (1, -1))])


def _cross(u, v) -> float:
    return float(u[0] * v[1] - u[1] * v[0])


def _inside(p, poly) -> bool:
    cross = [_cross(poly[(k + 1) % 4] - poly[k], p - poly[k]) for k in range(4)]
    return all(c >= -1e-12 for c in cross) or all(c <= 1e-12 for c in cross)


def _segments_cross(p0, p1, q0, q1) -> bool:
    d = lambda a, b, c: _cross(b - a, c - a)  # noqa: E731
    return d(p0, p1, q0) * d(p0, p1, q1) <= 0 and d(q0, q1, p0) * d(q0, q1, p1) <= 0


def overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Two convex quadrilaterals share a point: a corner of one inside the other, or edges cross."""
    if any(_inside(p, b) for p in a) or any(_inside(p, a) for p in b):
        return True
    return any(_segments_cross(a[i], a[(i + 1) % 4], b[k], b[(k + 1) % 4]) for i in range(4) for k in range(4))


def oracle_ttc(ca, ha, va, cb, hb, vb) -> float:
    """Translating convex polygons first touch where a corner of one meets an edge of the other:
    the least time over the 32 corner-edge pairs (a 2 x 2 solve each), 0 if they touch now."""
    a, b = corners(ca, ha), corners(cb, hb)
    if overlap(a, b):
        return 0.0
    best = math.inf
    for p_poly, q_poly, w in ((a, b, va - vb), (b, a, vb - va)):  # corner's motion against the edge's
        for p in p_poly:
            for k in range(4):
                q0, q1 = q_poly[k], q_poly[(k + 1) % 4]
                m = np.c_[w, q0 - q1]
                if abs(np.linalg.det(m)) < 1e-12:
                    continue
                t, u = np.linalg.solve(m, q0 - p)
                if t >= 0 and -1e-12 <= u <= 1 + 1e-12:
                    best = min(best, t)
    return best


def oracle_gap(a: np.ndarray, b: np.ndarray) -> float:
    if overlap(a, b):
        return 0.0

    def dist2(w):
        p, q = w[:4] @ a, w[4:] @ b
        return float(np.sum((p - q) ** 2))

    cons = [{"type": "eq", "fun": lambda w: w[:4].sum() - 1}, {"type": "eq", "fun": lambda w: w[4:].sum() - 1}]
    res = minimize(dist2, np.full(8, 0.25), bounds=[(0, 1)] * 8, constraints=cons, method="SLSQP",
                   options={"ftol": 1e-15, "maxiter": 500})  # fmt: skip
    return math.sqrt(res.fun)


def straight_scene(rng, vehicles=4, steps=6, dt=0.5):
    """Vehicles on straight lines at constant velocity (each present over a run of times)."""
    p0 = rng.uniform(-15, 15, size=(vehicles, 2))
    speed = rng.uniform(0, 12, size=vehicles)
    speed[0] = 0.0  # one stands (heading: +x)
    h = rng.uniform(-math.pi, math.pi, size=vehicles)
    v = speed[:, None] * np.c_[np.cos(h), np.sin(h)]
    t = np.arange(steps + 1) * dt
    pos = p0[None] + t[:, None, None] * v[None]
    inside = np.ones((steps + 1, vehicles), dtype=bool)
    inside[: rng.integers(0, 3), 1] = False  # vehicle 1 enters late
    inside[steps - 1 :, 2] = False  # vehicle 2 leaves early
    return SimpleNamespace(positions=pos, velocities=np.broadcast_to(v, pos.shape).copy(), in_roi=inside, dt=dt)


def oracle_pet(s, a, b) -> float:
    """Straight constant-velocity paths: where the lines cross within both driven paths, the
    intervals each vehicle covers the point (its centre within half its length), apart or not."""
    va, vb = s.velocities[0, a], s.velocities[0, b]
    ta, tb = np.flatnonzero(s.in_roi[:, a]), np.flatnonzero(s.in_roi[:, b])
    if len(ta) < 2 or len(tb) < 2 or np.hypot(*va) == 0 or np.hypot(*vb) == 0:
        return math.inf
    pa, pb = s.positions[ta[0], a], s.positions[tb[0], b]
    m = np.c_[va, -vb]
    if abs(np.linalg.det(m)) < 1e-12:
        return math.inf
    ua, ub = np.linalg.solve(m, pb - pa)  # seconds after each first time
    if not (0 <= ua <= (ta[-1] - ta[0]) * s.dt and 0 <= ub <= (tb[-1] - tb[0]) * s.dt):
        return math.inf
    end_a, end_b = (ta[-1] - ta[0]) * s.dt, (tb[-1] - tb[0]) * s.dt
    half_a, half_b = SIZE[0] / 2 / np.hypot(*va), SIZE[0] / 2 / np.hypot(*vb)
    ina, outa = max(ua - half_a, 0.0) + ta[0] * s.dt, ua + half_a + ta[0] * s.dt
    inb, outb = max(ub - half_b, 0.0) + tb[0] * s.dt, ub + half_b + tb[0] * s.dt
    outa = math.inf if ua + half_a > end_a else outa
    outb = math.inf if ub + half_b > end_b else outb
    return max(inb - outa, ina - outb, 0.0)


def heading_of(v, recorded: float = math.nan) -> float:
    """A vehicle's heading at constant velocity ``v``: its own when it moves at least the heading
    speed, else its recorded one where known, else +x."""
    if np.hypot(*v) >= 0.5:
        return math.atan2(v[1], v[0])
    return recorded if math.isfinite(recorded) else 0.0


@pytest.mark.parametrize("recorded", [False, True])
@pytest.mark.parametrize("seed", range(6))
def test_measures_match_the_oracle_on_straight_scenes(seed: int, recorded: bool) -> None:
    rng = np.random.default_rng(seed)
    s = straight_scene(rng)
    given = np.full(s.in_roi.shape, np.nan)
    if recorded:  # the standing vehicle's recorded heading (a moving one's is not used)
        given[:, :2] = rng.uniform(-math.pi, math.pi, size=2)
        s.headings = given
    c = criticality(s, size=SIZE)
    assert isinstance(c, Criticality) and c.n_scenes == 1
    seen = 0
    for i in range(len(c.pairs["a"])):
        a, b = c.pairs["a"][i], c.pairs["b"][i]
        both = np.flatnonzero(s.in_roi[:, a] & s.in_roi[:, b])
        ha, hb = heading_of(s.velocities[0, a], given[0, a]), heading_of(s.velocities[0, b], given[0, b])
        ttc = min(
            oracle_ttc(s.positions[t, a], ha, s.velocities[t, a], s.positions[t, b], hb, s.velocities[t, b])
            for t in both
        )
        gap = min(oracle_gap(corners(s.positions[t, a], ha), corners(s.positions[t, b], hb)) for t in both)
        hit = any(overlap(corners(s.positions[t, a], ha), corners(s.positions[t, b], hb)) for t in both)
        assert c.pairs["ttc"][i] == pytest.approx(ttc, abs=1e-6) or (math.isinf(ttc) and math.isinf(c.pairs["ttc"][i]))
        assert c.pairs["gap"][i] == pytest.approx(gap, abs=1e-6)
        assert bool(c.pairs["collision"][i]) == hit
        pet = oracle_pet(s, a, b)
        assert c.pairs["pet"][i] == pytest.approx(pet, abs=1e-9) or (math.isinf(pet) and math.isinf(c.pairs["pet"][i]))
        seen += 1
    assert seen == 6  # every pair of the 4 vehicles is in the scene together at some time
    np.testing.assert_array_equal(c.vehicles["deceleration"], 0.0)  # constant speeds
    with pytest.raises(InvalidInputError, match="headings"):
        criticality(SimpleNamespace(**{**vars(s), "headings": np.full(s.in_roi.shape, np.inf)}), size=SIZE)


def test_recorded_frames_as_scenes(tmp_path) -> None:
    """Windows of consecutive frames, vehicles followed by track id: a vehicle that leaves and
    one that enters take their own columns, and the measures are those of the window's grid."""
    import pandas as pd

    rows = []
    for t in range(8):
        rows.append({"track": 1, "t": t * 0.5, "x": 5.0 * t * 0.5, "y": 0.0})
        if t >= 2:
            rows.append({"track": 2, "t": t * 0.5, "x": 30.0 - 4.0 * (t - 2) * 0.5, "y": 0.5})
        if t < 4:
            rows.append({"track": 3, "t": t * 0.5, "x": -20.0, "y": 3.5 * t * 0.5})
    frames = dpgp.make_frames(pd.DataFrame(rows), dt=0.5)
    scenes = recorded_scenes(frames, 3)
    assert [s.positions.shape[0] for s in scenes] == [4, 4]
    first = scenes[0]
    np.testing.assert_array_equal(first.tracks, [1, 2, 3])
    np.testing.assert_array_equal(first.in_roi[:, 1], [False, False, True, True])
    c = criticality(frames, steps=3, size=SIZE)
    assert c.n_scenes == 2
    direct = criticality(scenes, size=SIZE)
    for k in c.pairs:
        np.testing.assert_array_equal(c.pairs[k], direct.pairs[k])
    with pytest.raises(InvalidInputError, match="steps"):
        recorded_scenes(frames, -1)


def test_a_recorded_vehicle_standing_through_a_window_faces_the_way_it_last_moved() -> None:
    """Two vehicles that drove north and stand side by side, 3 apart (wider than a car, shorter
    than one): facing +x (the heading of a vehicle that never moves) their rectangles overlap; the
    frames' ``prev_heading`` turns them north, and they do not."""
    import pandas as pd

    rows = []
    for t in range(10):
        y = 3.0 * min(t, 3) * 0.5  # north at 3 for 1.5 s, then standing
        rows += [{"track": k, "t": t * 0.5, "x": 3.0 * k, "y": y} for k in (1, 2)]
    frames = dpgp.make_frames(pd.DataFrame(rows), dt=0.5)
    standing = recorded_scenes(frames, 3, stride=5)[1]  # times 2.5-4 s: both stand throughout
    assert np.all(np.hypot(*np.moveaxis(standing.velocities, 2, 0)) == 0)
    np.testing.assert_allclose(standing.headings, math.pi / 2)
    c = criticality([standing], size=SIZE)
    assert not c.pairs["collision"][0] and c.pairs["gap"][0] == pytest.approx(3.0 - SIZE[1])
    blind = RecordedScene(standing.positions, standing.velocities, standing.in_roi, standing.tracks, standing.dt)
    assert criticality([blind], size=SIZE).pairs["collision"][0]


def test_the_default_size_is_the_recorded_one_else_a_car_in_the_frames_unit() -> None:
    from dpgp.generate.criticality import DEFAULT_SIZE, default_size

    assert default_size(None) == DEFAULT_SIZE
    assert default_size(SimpleNamespace(object_size=(5.0, 2.0), length_unit="m")) == (5.0, 2.0)
    ft = default_size(SimpleNamespace(object_size=None, length_unit="ft"))
    assert ft == pytest.approx((DEFAULT_SIZE[0] / 0.3048, DEFAULT_SIZE[1] / 0.3048))


def test_a_generated_steering_vehicle_standing_faces_its_heading() -> None:
    """Generated scenes of steering vehicles carry each vehicle's heading (``Simulation.headings``):
    a vehicle standing through a scene has velocity 0 and so no heading of its own, and its
    rectangle faced +x beside its neighbour's. The same standing pair as from recorded frames,
    as a generated scene; and a steering model's scenes carry headings exactly where their
    vehicles are there."""
    import dataclasses

    from dpgp.generate import motion
    from dpgp.generate.rollout import Simulation

    t = np.arange(4) * 0.5
    pos = np.broadcast_to(np.array([[0.0, 0.0], [3.0, 0.0]]), (4, 2, 2)).copy()
    still = dict(positions=pos, velocities=np.zeros_like(pos), t=t, in_roi=np.ones((4, 2), bool),
                 low_data=np.zeros((4, 2), bool), pattern=0, method="euler", stochastic=True,
                 roi=(-50.0, 50.0, -50.0, 50.0), dynamics="interactive")  # fmt: skip
    north = Simulation(**still, headings=np.full((4, 2), math.pi / 2))
    c = criticality(north, size=SIZE)
    assert not c.pairs["collision"][0] and c.pairs["gap"][0] == pytest.approx(3.0 - SIZE[1])
    assert criticality(Simulation(**still), size=SIZE).pairs["collision"][0]

    model = dpgp.DPGP.load(Path(__file__).parents[1] / "fixtures" / "field_model.npz")
    fit = model._fitted()
    base = motion.motion_model(fit)
    assert not base.steers and model.sample_scenarios(5, steps=3, seed=2).simulations[0].headings is None
    steering = dataclasses.replace(base, sigma_frame="heading", min_speed=0.1, tau_heading=2.0)
    fit.cache["motion"] = (fit.frames, steering)
    try:
        sims = model.sample_scenarios(30, steps=6, seed=2).simulations
    finally:
        fit.cache["motion"] = (fit.frames, base)
    for s in sims:
        assert s.headings is not None and s.headings.shape == s.in_roi.shape
        np.testing.assert_array_equal(np.isfinite(s.headings), s.in_roi)
