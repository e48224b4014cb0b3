"""Scale-aware defaults (dpgp.defaults): the resolved values against numpy/scipy oracles, their
behaviour under a change of units, the paper preset, and model files that keep them."""

from __future__ import annotations

import numpy as np
import pytest

import dpgp
from dpgp.gp import defaults

FT = 0.3048  # metres per foot


@pytest.fixture(scope="module")
def small():
    return dpgp.datasets.synthetic("intersection", n_frames=40, seed=5)


def scaled(frames, c):
    out = dpgp.Frames(frames.ids, frames.offsets, frames.xy * c, frames.v * c, frames.labels)
    out.summary = frames.summary
    return out


def test_vehicle_spacing_is_the_median_nearest_neighbour_distance(small):
    nearest = []
    for f in small:
        d = np.sqrt(((f.xy[:, None] - f.xy[None]) ** 2).sum(-1)) + np.diag(np.full(len(f), np.inf))
        nearest.extend(d.min(axis=1))
    assert defaults.vehicle_spacing(small) == pytest.approx(np.median(nearest), rel=1e-12)


def test_each_vehicles_nearest_neighbour_in_the_core_is_numpys():
    rng = np.random.default_rng(3)
    sizes = [1, 5, 2, 1, 9, 3]  # frames of one vehicle have no neighbour and are left out
    xy = rng.uniform(-50, 50, size=(sum(sizes), 2))
    offsets = np.r_[0, np.cumsum(sizes)]
    want = []
    for a, b in zip(offsets[:-1], offsets[1:]):
        if b - a >= 2:
            d2 = ((xy[a:b, None] - xy[None, a:b]) ** 2).sum(-1) + np.diag(np.full(b - a, np.inf))
            want.extend(d2.min(axis=1))
    got = dpgp._core.nearest_neighbour_sq(xy, offsets.astype(np.int64))
    np.testing.assert_allclose(got, want, rtol=1e-14)


def test_vehicle_spacing_falls_back_to_area_per_vehicle():
    f = dpgp.Frames.from_arrays([0, 1, 2], [0.0, 4.0, 2.0], [0.0, 1.0, 9.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0])
    assert defaults.vehicle_spacing(f) == pytest.approx(np.sqrt(4.0 * 9.0 / 1.0))


def test_refine_grid_finds_the_vertex_of_a_parabola_in_log_noise():
    grid = 10.0 ** np.arange(-3.5, -0.4, 0.5)
    c = np.log(0.013)
    scores = -((np.log(grid) - c) ** 2)
    want = np.polyfit(np.log(grid[2:5]), scores[2:5], 2)  # the oracle: numpy's least-squares parabola
    assert defaults.refine_grid(grid, scores) == pytest.approx(np.exp(-want[1] / (2 * want[0])), rel=1e-9)
    assert defaults.refine_grid(grid, -grid) == grid[0]  # best at an end: the end
    assert defaults.refine_grid(grid, np.r_[np.nan, scores[1:]]) == pytest.approx(0.013, rel=1e-9)


def test_estimate_noise_var_scans_fractions_of_each_components_variance(small):
    """Coordinate ascent over ρ = noise / signal variance: both together, then x, then y; on a
    score separable and quadratic in log σ_n² the parabola refinement lands on the optimum."""
    calls = []

    def pilot(train, test, noise, prior):
        calls.append((len(train), len(test), noise, prior))
        return -((np.log(noise[0]) - np.log(0.05)) ** 2) - 0.5 * (np.log(noise[1]) - np.log(3.0)) ** 2

    sv, grid = (2.0, 6.0), list(defaults.NOISE_GRID)
    noise, trace = defaults.estimate_noise_var(small, sv, (10.0, 0.5), pilot)
    assert {(c[0], c[1], c[3]) for c in calls} == {(28, 12, (10.0, 0.5))}  # 70/30 in time
    assert len(calls) == len(trace) == 3 * len(grid)
    rho = np.array([c[2] for c in calls]) / sv
    n = len(grid)
    assert rho[:n, 0] == pytest.approx(grid) and rho[:n, 1] == pytest.approx(grid)  # one ρ for both
    assert rho[n : 2 * n, 0] == pytest.approx(grid) and np.ptp(rho[n : 2 * n, 1]) == 0  # then x
    assert rho[2 * n :, 1] == pytest.approx(grid) and rho[2 * n :, 0] == pytest.approx(0.05 / 2.0)  # then y
    assert noise == pytest.approx((0.05, 3.0), rel=1e-9)
    assert [t[:2] for t in trace] == [pytest.approx(tuple(r)) for r in rho]


def test_spread_takes_frames_evenly_in_order(small):
    sub = defaults.spread(small, 5)
    np.testing.assert_array_equal(sub.ids, small.ids[[0, 10, 20, 29, 39]])
    assert defaults.spread(small, 100) is small


def test_auto_values_scale_with_the_units(small):
    pilot = dpgp.DPGP(seed=2)._pilot_fit
    kw = dict(preset=None, assignment="gibbs", noise_var="pilot", length_scale_prior="auto", pilot=pilot)
    a = defaults.resolve(small, **kw)
    b = defaults.resolve(scaled(small, FT), **kw)
    assert b.length_scale_prior[0] == a.length_scale_prior[0]
    assert b.length_scale_prior[1] == pytest.approx(a.length_scale_prior[1] * FT, rel=1e-12)
    assert b.noise_var == pytest.approx(tuple(np.array(a.noise_var) * FT**2), rel=1e-6)
    # the pilots' held-out scores move by the Jacobian of the change of units only
    n_test = defaults.spread(small, defaults.PILOT_FRAMES)[28:].n_points
    for (*ra, sa), (*rb, sb) in zip(a.noise_scores, b.noise_scores):
        assert rb == pytest.approx(ra, rel=1e-9) and sb == pytest.approx(sa - 2 * n_test * np.log(FT), abs=1e-6)
    assert (a.noise_var_source, a.length_scale_prior_source) == ("pilot", "auto")
    # noise_var="auto" (sampled per pattern) and "global": the chain starts at the prior's median
    # share of each variance
    assert defaults.resolve(small, **{**kw, "noise_var": "global"}).noise_var_source == "sampled"
    s = defaults.resolve(small, **{**kw, "noise_var": "auto"})
    t = defaults.resolve(scaled(small, FT), **{**kw, "noise_var": "auto"})
    assert s.noise_var_source == "per_pattern" and s.noise_scores is None
    assert s.noise_var == pytest.approx(tuple(np.exp(defaults.NOISE_PRIOR[0]) * small.v.var(axis=0)), rel=1e-12)
    assert t.noise_var == pytest.approx(tuple(np.array(s.noise_var) * FT**2), rel=1e-12)


def test_explicit_values_and_the_paper_preset(small):
    r = defaults.resolve(small, preset=None, assignment="gibbs", noise_var=0.5, length_scale_prior=(3, 2))
    assert (r.noise_var, r.length_scale_prior, r.assignment) == ((0.5, 0.5), (3.0, 2.0), "gibbs")
    p = defaults.resolve(small, preset="paper", assignment="gibbs", noise_var="auto", length_scale_prior="auto")
    assert (p.noise_var, p.length_scale_prior, p.assignment) == ((1.0, 1.0), (10.0, 1.0), "map")
    q = defaults.resolve(small, preset="paper", assignment="gibbs", noise_var=(0.2, 3.0), length_scale_prior="auto")
    assert (q.noise_var, q.noise_var_source, q.length_scale_prior_source) == ((0.2, 3.0), "user", "paper")


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(noise_var="big"), "noise_var"),
        (dict(noise_var=-1.0), "noise_var"),
        (dict(noise_var=float("nan")), "noise_var"),
        (dict(noise_var=(1.0, 2.0, 3.0)), "noise_var"),
        (dict(noise_var=(1.0, 0.0)), "noise_var"),
        (dict(length_scale_prior="wide"), "length_scale_prior"),
        (dict(length_scale_prior=(10.0, 0.0)), "length_scale_prior"),
        (dict(preset="book"), "preset"),
    ],
)
def test_bad_settings_raise_typed_errors(small, kw, match):
    with pytest.raises(dpgp.InvalidInputError, match=match):
        dpgp.DPGP(iterations=1, progress=False, **kw).fit(small)


def test_paper_preset_is_the_paper_settings(small):
    a = dpgp.DPGP.paper(iterations=3, seed=1, progress=False).fit(small)
    b = dpgp.DPGP(
        iterations=3, seed=1, progress=False, assignment="map", noise_var=1.0, length_scale_prior=(10.0, 1.0)
    ).fit(small)
    assert (a.assignment_, a.noise_var_, a.length_scale_prior_) == ("map", (1.0, 1.0), (10.0, 1.0))
    assert a.preset == "paper" and "preset='paper'" in repr(a)
    np.testing.assert_array_equal(a.labels_, b.labels_)
    np.testing.assert_allclose(a.length_scales_, b.length_scales_)


def test_model_file_keeps_the_resolved_values(small, tmp_path):
    m = dpgp.DPGP(iterations=2, seed=0, progress=False).fit(small)
    m.save(tmp_path / "m.npz")
    back = dpgp.DPGP.load(tmp_path / "m.npz")
    assert back.noise_var == "auto" and back.length_scale_prior == "auto"
    assert back.noise_var_ == m.noise_var_ and back.length_scale_prior_ == m.length_scale_prior_
    assert back.defaults_ == m.defaults_
    np.testing.assert_array_equal(back.score_samples(small[:5]), m.score_samples(small[:5]))


@pytest.mark.parametrize("proposal", ["full", "informed"])
def test_us101_feet_to_metres_gives_the_same_fit(us101_path, proposal):
    """Unit invariance on real data: the same partition, and the same log density up to the
    Jacobian of the change of units (2 l log c per frame of l vehicles)."""
    frames = dpgp.read_frames(us101_path)[:120]
    train, test = frames[:90], frames[90:]
    ft = dpgp.DPGP(iterations=4, seed=3, progress=False, proposal=proposal).fit(train)
    m = dpgp.DPGP(iterations=4, seed=3, progress=False, proposal=proposal).fit(scaled(train, FT))
    assert m.noise_var_ == pytest.approx(tuple(np.array(ft.noise_var_) * FT**2), rel=1e-6)
    assert dpgp.adjusted_rand_index(ft.labels_, m.labels_) >= 0.95
    jac = 2 * test.sizes * np.log(FT)
    np.testing.assert_allclose(
        m.score_samples(scaled(test, FT), positions=False),
        ft.score_samples(test, positions=False) - jac,
        rtol=1e-6,
        atol=1e-4,
    )
