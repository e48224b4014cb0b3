"""Rollouts: the Rust integrator against exact solutions (constant and rotational fields, with
Euler's and RK4's orders), and model.simulate against a numpy re-implementation through the
model's own velocity field."""

from __future__ import annotations

import numpy as np
import pytest

import dpgp
from dpgp.generate.simulation import DEFAULT_DT, Simulation, default_dt, default_roi, integrate_affine

ROT = [[0.0, -1.0], [1.0, 0.0]]  # v(p) = (-y, x): rigid rotation at 1 rad/s
START = np.array([[1.0, 0.0], [0.0, 2.0], [-0.5, -0.5]])


def rotated(t: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Exact positions (T, l, 2) of the rotation."""
    c, s = np.cos(t)[:, None], np.sin(t)[:, None]
    return np.stack([start[:, 0] * c - start[:, 1] * s, start[:, 0] * s + start[:, 1] * c], axis=-1)


@pytest.fixture(scope="module")
def model() -> dpgp.DPGP:
    frames = dpgp.datasets.synthetic("intersection", n_frames=48, seed=3)
    return dpgp.DPGP(iterations=2, seed=0, progress=False).fit(frames)


@pytest.mark.parametrize("method", ["euler", "rk4"])
def test_constant_field_reaches_the_analytic_positions(method):
    sim = integrate_affine(START, np.zeros((2, 2)), (3.0, -1.5), steps=40, dt=0.25, method=method)
    want = START[None] + sim.t[:, None, None] * np.array([3.0, -1.5])
    np.testing.assert_allclose(sim.positions, want, rtol=0, atol=1e-12)
    assert sim.positions.shape == (41, 3, 2) and sim.in_roi.all()
    np.testing.assert_array_equal(sim.velocities, np.broadcast_to([3.0, -1.5], (41, 3, 2)))


def _errors(method: str, dts: list[float]) -> np.ndarray:
    errs = []
    for dt in dts:
        steps = int(round(2.0 / dt))
        sim = integrate_affine(START, ROT, (0.0, 0.0), steps=steps, dt=dt, method=method)
        errs.append(np.abs(sim.positions - rotated(sim.t, START)).max())
    return np.array(errs)


def test_rotational_field_euler_is_first_order_and_rk4_fourth():
    dts = [0.1, 0.05, 0.025, 0.0125]
    euler, rk4 = _errors("euler", dts), _errors("rk4", dts)
    euler_order = np.log2(euler[:-1] / euler[1:])
    rk4_order = np.log2(rk4[:-1] / rk4[1:])
    np.testing.assert_allclose(euler_order, 1.0, atol=0.06)
    np.testing.assert_allclose(rk4_order, 4.0, atol=0.05)
    assert rk4[-1] < 1e-8 < euler[-1] * 1e-4  # and RK4 is far more accurate at every step size
    # A full turn with 100 RK4 steps comes back to the start.
    sim = integrate_affine(START, ROT, steps=100, dt=2 * np.pi / 100, method="rk4")
    np.testing.assert_allclose(sim.positions[-1], START, atol=1e-5)  # Euler: off by ~0.2 r


def test_vehicles_stop_when_they_leave_the_roi():
    sim = integrate_affine(
        [[0.0, 0.0], [9.0, 5.0]], np.zeros((2, 2)), (2.0, 0.0), steps=10, dt=1.0, roi=(-10, 10, -10, 10)
    )
    # vehicle 1 reaches x = 11 (outside) at step 1 and stands there, velocity 0
    assert sim.in_roi[0, 1] and not sim.in_roi[1:, 1].any()
    np.testing.assert_array_equal(sim.positions[1:, 1], np.broadcast_to([11.0, 5.0], (10, 2)))
    np.testing.assert_array_equal(sim.velocities[1:, 1], 0.0)
    # vehicle 0: x = 10 at step 5 is on the edge (inside), 12 at step 6 is out
    assert sim.in_roi[5, 0] and not sim.in_roi[6, 0]
    assert sim.positions[-1, 0, 0] == 12.0


def _numpy_rollout(model, k, xy, steps, dt, method, roi):
    """The same rollout in numpy through model.velocity_field (the posterior mean)."""
    field = lambda p: model.velocity_field(k, p)[0]  # noqa: E731
    x0, x1, y0, y1 = roi
    x, inside = xy.copy(), np.ones(len(xy), bool)
    inside &= (x[:, 0] >= x0) & (x[:, 0] <= x1) & (x[:, 1] >= y0) & (x[:, 1] <= y1)
    out = [x.copy()]
    for _ in range(steps):
        k1 = field(x)
        if method == "euler":
            inc = k1
        else:
            k2 = field(x + 0.5 * dt * k1)
            k3 = field(x + 0.5 * dt * k2)
            k4 = field(x + dt * k3)
            inc = (k1 + 2 * k2 + 2 * k3 + k4) / 6
        x = np.where(inside[:, None], x + dt * inc, x)
        inside &= (x[:, 0] >= x0) & (x[:, 0] <= x1) & (x[:, 1] >= y0) & (x[:, 1] <= y1)
        out.append(x.copy())
    return np.array(out)


@pytest.mark.parametrize("method", ["euler", "rk4"])
def test_model_rollout_follows_the_posterior_mean(model, method):
    sim = model.simulate(5, steps=25, method=method, dynamics="field")  # the paper's rollout
    assert isinstance(sim, Simulation) and sim.pattern == model.labels_[5]
    want = _numpy_rollout(model, sim.pattern, model.frames_[5].xy, 25, DEFAULT_DT, method, default_roi(model))
    np.testing.assert_allclose(sim.positions, want, rtol=1e-9, atol=1e-9)
    moving = sim.in_roi[0]
    mean, _ = model.velocity_field(sim.pattern, sim.positions[0])
    np.testing.assert_allclose(sim.velocities[0][moving], mean[moving], rtol=1e-9, atol=1e-9)
    assert (~sim.in_roi[-1]).any(), "through vehicles should have left the ROI in 12.5 s"


def test_default_pattern_is_the_map_assignment(model):
    frame = model.frames_[7]
    sim = model.simulate(frame, steps=2)
    one = dpgp.Frames(np.array([0]), np.array([0, len(frame)]), frame.xy, frame.v)
    assert sim.pattern == model.predict(one)[0]
    assert model.simulate(7, steps=2).pattern == model.labels_[7]
    other = (model.labels_[7] + 1) % model.n_patterns_
    assert model.simulate(7, pattern=other, steps=2).pattern == other
    # x, y, vx, vy rows behave like the frame; positions alone need a pattern
    np.testing.assert_array_equal(
        model.simulate(np.c_[frame.xy, frame.v], steps=3).positions, model.simulate(frame, steps=3).positions
    )
    with pytest.raises(dpgp.InvalidInputError, match="pattern="):
        model.simulate(frame.xy, steps=2)
    assert model.simulate(frame.xy, pattern=0, steps=2).pattern == 0


def test_stochastic_rollouts_are_seeded_and_vary(model):
    a = model.simulate(0, steps=10, stochastic=True, seed=11, dynamics="field")
    b = model.simulate(0, steps=10, stochastic=True, seed=11, dynamics="field")
    c = model.simulate(0, steps=10, stochastic=True, seed=12, dynamics="field")
    mean = model.simulate(0, steps=10, dynamics="field")
    np.testing.assert_array_equal(a.positions, b.positions)
    assert not np.array_equal(a.positions, c.positions)
    assert not np.array_equal(a.positions, mean.positions)
    assert a.stochastic and not mean.stochastic
    # the seed only matters for stochastic rollouts
    np.testing.assert_array_equal(model.simulate(0, steps=10, seed=5, dynamics="field").positions, mean.positions)
    # draws scatter around the mean by about the posterior standard deviation
    _, var = model.velocity_field(a.pattern, a.positions[0])
    dev = (a.velocities[0] - mean.velocities[0]) / np.sqrt(var + 1e-12)
    assert np.all(np.abs(dev) < 6)


def test_low_data_regions_are_flagged(model):
    far = np.array([[400.0, 400.0]])
    sim = model.simulate(far, pattern=0, steps=3, roi=(-500, 500, -500, 500))
    assert sim.low_data[:, 0].all()
    near = model.simulate(model.frames_[int(np.flatnonzero(model.labels_ == 0)[0])], pattern=0, steps=0)
    assert not near.low_data.any()
    # threshold None: no flags computed; a huge threshold: nothing flagged
    assert not model.simulate(
        far, pattern=0, steps=3, roi=(-500, 500, -500, 500), low_data_threshold=None
    ).low_data.any()
    assert not model.simulate(
        far, pattern=0, steps=3, roi=(-500, 500, -500, 500), low_data_threshold=2.0
    ).low_data.any()


def test_defaults_and_table(model):
    sim = model.simulate(0, steps=4)
    assert default_dt(model) == DEFAULT_DT  # synthetic frames carry no time step
    np.testing.assert_allclose(sim.t, np.arange(5) * 0.5)
    assert sim.roi == model.frames_.bounds()
    assert model.simulate(0, steps=4, dt=0.1).dt == pytest.approx(0.1)
    df = sim.to_pandas()
    assert list(df.columns) == ["step", "t", "vehicle", "x", "y", "vx", "vy", "in_roi", "low_data"]
    assert len(df) == 5 * sim.n_vehicles
    np.testing.assert_array_equal(df["x"].to_numpy().reshape(5, -1), sim.positions[..., 0])
    assert "Simulation(pattern" in repr(sim)


class _Summary:
    dt = 0.04
    roi = (0.0, 1.0, 0.0, 2.0)


def test_dt_and_roi_come_from_the_framing_summary():
    class M:
        frames_ = type("F", (), {"summary": _Summary()})()

    assert default_dt(M()) == 0.04
    assert default_roi(M()) == (0.0, 1.0, 0.0, 2.0)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(method="midpoint"), "method"),
        (dict(steps=-1), "steps"),
        (dict(dt=0.0), "dt"),
        (dict(pattern=99), "pattern"),
        (dict(low_data_threshold=-1.0), "low_data_threshold"),
        (dict(roi=(1, 0, 0, 1)), "roi"),
        (dict(stochastic=True, seed=-3), "seed"),
    ],
)
def test_bad_arguments_raise_typed_errors(model, kwargs, match):
    with pytest.raises(dpgp.InvalidInputError, match=match):
        model.simulate(0, **{"steps": 2, **kwargs})


def test_bad_frames_raise_typed_errors(model):
    with pytest.raises(dpgp.InvalidInputError, match="out of range"):
        model.simulate(10_000)
    with pytest.raises(dpgp.ShapeError):
        model.simulate(np.zeros((3, 3)), pattern=0)
    with pytest.raises(dpgp.InvalidInputError, match="non-finite"):
        model.simulate(np.array([[np.nan, 0.0]]), pattern=0)
    with pytest.raises(dpgp.NotFittedError):
        dpgp.DPGP().simulate(0)
