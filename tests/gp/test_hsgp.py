"""The reduced-rank likelihood (likelihood="hsgp") against plain numpy oracles:

(a) the basis sizing rule against its documented formula;
(b) marginal likelihood, joint predictive and posterior (computed in Rust through the M x M
    statistics) against the dense n x n kernel k̃ in numpy (hsgp_oracle + gp_oracle);
(c) accuracy against the exact GP at the default basis size, per-frame log predictive density,
    at length scales in the prior's bulk, on US-101 and on a synthetic intersection;
(d) a fitted hsgp model works like an exact one: fields, simulation, scenarios, scores, files.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import gamma

import dpgp
from dpgp.hsgp import Basis

import gp_oracle
import hsgp_oracle
import sampler_oracle as so


# --- (a) sizing rule ------------------------------------------------------------------------------
@pytest.mark.parametrize("prior", [(10.0, 1.0), (4.0, 3.0), (10.0, 0.2)])
def test_basis_rule_follows_its_formula(prior):
    rng = np.random.default_rng(1)
    xy = np.column_stack([rng.uniform(0, 72, 500), rng.uniform(1350, 1550, 500)])
    b = dpgp.hsgp.basis_for(xy, prior)
    lo, mid = gamma(prior[0], scale=prior[1]).ppf([0.05, 0.5])
    want = []
    for d in range(2):
        s = max(np.ptp(xy[:, d]) / 2, lo)
        half = max(1.2 * s, s + 2 * mid)
        assert b.center[d] == pytest.approx((xy[:, d].min() + xy[:, d].max()) / 2)
        assert b.half_widths[d] == pytest.approx(half, rel=1e-9)
        want.append(max(int(np.ceil(2 * half / lo)), 4))
    total = want[0] * want[1]
    if total > dpgp.hsgp.MAX_BASIS:  # both counts shrink in proportion
        want = [int(np.floor(w * np.sqrt(dpgp.hsgp.MAX_BASIS / total))) for w in want]
    assert b.counts == tuple(want)
    assert b.size <= dpgp.hsgp.MAX_BASIS
    assert dpgp.hsgp.basis_for(xy, prior, n_basis=(7, 9)).counts == (7, 9)
    assert dpgp.hsgp.basis_for(xy, prior, length_scales=(20.0, 30.0)).counts[1] < 40


def test_bad_basis_settings_are_typed_errors():
    xy = np.zeros((3, 2))
    for bad in [(0, 3), (100, 100), (2.5, 3), "big", (1,)]:
        with pytest.raises(dpgp.InvalidInputError):
            dpgp.hsgp.basis_for(xy, n_basis=bad)
    with pytest.raises(dpgp.InvalidInputError):
        dpgp.DPGP(likelihood="hsgp", n_basis=(0, 1)).fit(dpgp.datasets.synthetic("highway", 5))
    with pytest.raises(dpgp.InvalidInputError):
        dpgp.DPGP(likelihood="sparse").fit(dpgp.datasets.synthetic("highway", 5))
    with pytest.raises(dpgp.InvalidInputError):
        dpgp.DPGP(proposal="smart").fit(dpgp.datasets.synthetic("highway", 5))
    with pytest.raises(dpgp.InvalidInputError):
        dpgp.hsgp.log_marginal_likelihood(
            [[np.nan, 0.0]], [[0.0, 0.0]], dpgp.GPParams((1.0, 1.0)), Basis((0, 0), (1, 1), (2, 2))
        )


# --- (b) densities against the dense oracle --------------------------------------------------------
def random_case(rng, n, equal_signal):
    xy = np.column_stack([rng.uniform(-20, 20, n), rng.uniform(0, 60, n)])
    v = np.column_stack([np.sin(xy[:, 1] / 9) + rng.normal(0, 0.5, n), 3 + xy[:, 0] / 8 + rng.normal(0, 0.5, n)])
    sv = (2.0, 2.0) if equal_signal else (0.7, 3.0)
    noise = rng.uniform(0.2, 1.5, size=2) if rng.random() < 0.5 else rng.uniform(0.2, 1.5)
    p = so.Params((rng.uniform(3, 9), rng.uniform(5, 15)), sv, noise, (0.3, 2.0))
    basis = Basis((0.0, 30.0), (35.0, 50.0), (int(rng.integers(3, 14)), int(rng.integers(3, 14))))
    return xy, v, p, basis


@pytest.mark.parametrize("n", [1, 4, 30, 250])
@pytest.mark.parametrize("equal_signal", [True, False])
def test_densities_match_the_dense_reduced_rank_kernel(n, equal_signal):
    rng = np.random.default_rng(n + 10 * equal_signal)
    for _ in range(3):
        xy, v, p, basis = random_case(rng, n + 6, equal_signal)
        gp = dpgp.GPParams(p.length_scales, p.signal_var, p.noise_var, p.mean)
        po = so.Params(p.length_scales, p.signal_var, p.noise_var, p.mean, basis)
        train, test = slice(0, n), slice(n, n + 6)
        got = dpgp.hsgp.log_marginal_likelihood(xy[train], v[train], gp, basis)
        np.testing.assert_allclose(got, gp_oracle.log_marginal_likelihood(xy[train], v[train], po), rtol=1e-9)
        got = dpgp.hsgp.log_predictive(xy[train], v[train], xy[test], v[test], gp, basis)
        want = gp_oracle.log_predictive(xy[train], v[train], xy[test], v[test], po)
        np.testing.assert_allclose(got, want, rtol=1e-8, atol=1e-8)
        q = np.vstack([xy[test], [[100.0, 0.0], [0.0, -90.0]]])  # two queries outside the box
        mean, var = dpgp.hsgp.posterior(xy[train], v[train], q, gp, basis)
        wm, wv = gp_oracle.posterior(xy[train], v[train], q, po)
        out = ~hsgp_oracle.inside(q, basis)
        wv[out] = np.asarray(p.signal_var)  # the documented convention outside the box
        np.testing.assert_allclose(mean, wm, rtol=1e-8, atol=1e-8)
        np.testing.assert_allclose(var, wv, rtol=1e-7, atol=1e-8 * max(p.signal_var))


# --- (c) accuracy against the exact GP --------------------------------------------------------------
def frame_deltas(frames, train_idx, test_idx, prior, **basis_kw):
    """hsgp − exact per-frame log predictive density at the prior median length scales."""
    median = float(gamma(prior[0], scale=prior[1]).median())
    train = frames[np.asarray(train_idx)]
    basis = dpgp.hsgp.basis_for(frames.xy, prior, **basis_kw)
    p = dpgp.GPParams((median, median), frames.v.var(axis=0), 1.0, frames.v.mean(axis=0))
    out = []
    for i in test_idx:
        f = frames[int(i)]
        exact = dpgp.gp.log_predictive(train.xy, train.v, f.xy, f.v, p)
        approx = dpgp.hsgp.log_predictive(train.xy, train.v, f.xy, f.v, p, basis)
        out.append(approx - exact)
    return np.abs(out), basis


def test_accuracy_on_us101(us101_path):
    frames = dpgp.read_frames(us101_path)
    d, basis = frame_deltas(frames, range(0, 200, 4), range(1, 200, 5), (10.0, 1.0))
    print(f"US-101, M = {basis.size} {basis.counts}: median |Δ| {np.median(d):.4f}, max {d.max():.4f} nats")
    assert np.median(d) <= 0.05 and d.max() <= 0.5


def test_accuracy_on_a_synthetic_intersection():
    frames = dpgp.datasets.synthetic("intersection", n_frames=160, seed=2)
    same = np.flatnonzero(frames.labels == 0)
    d, basis = frame_deltas(frames, same[:30], np.r_[same[30:40], np.flatnonzero(frames.labels != 0)[:20]], (10.0, 1.0))
    print(f"intersection, M = {basis.size} {basis.counts}: median |Δ| {np.median(d):.4f}, max {d.max():.4f} nats")
    assert np.median(d) <= 0.05 and d.max() <= 0.5


# --- (d) a fitted model ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def fitted():
    frames = dpgp.datasets.synthetic("intersection", n_frames=120, seed=4)
    m = dpgp.DPGP(
        iterations=6, likelihood="hsgp", noise_var=1.0, length_scale_prior=(10.0, 1.0), seed=2, progress=False
    )
    return frames, m.fit(frames)


def test_hsgp_fit_recovers_patterns_and_reports_its_engine(fitted):
    frames, m = fitted
    assert m.likelihood_ == "hsgp" and m.basis_ is not None and m.basis_.size > 100
    assert dpgp.adjusted_rand_index(m.labels_, frames.labels) >= 0.9


def test_hsgp_model_uses_work(fitted, tmp_path):
    frames, m = fitted
    mean, var = m.velocity_field(0, [[3.0, 0.0], [0.0, 3.0], [500.0, 500.0]])
    assert mean.shape == var.shape == (3, 2) and np.all(np.isfinite(mean)) and np.all(var >= 0)
    assert np.allclose(var[2], m.params_.signal_var)  # outside the basis box: the prior
    sim = m.simulate(frames[0], steps=5, stochastic=True, seed=1)
    assert np.all(np.isfinite(sim.positions)) and np.all(np.isfinite(sim.velocities))
    sc = m.sample_scenarios(3, steps=4, seed=2)
    assert len(sc.to_pandas()) > 0
    s = m.score_samples(frames[:10])
    assert np.all(np.isfinite(s))
    proba = m.predict_proba(frames[:10])
    m.save(tmp_path / "m.npz")
    back = dpgp.DPGP.load(tmp_path / "m.npz")
    assert back.likelihood_ == "hsgp" and back.basis_ == m.basis_
    np.testing.assert_allclose(back.predict_proba(frames[:10]), proba, rtol=1e-10, atol=1e-12)
    np.testing.assert_array_equal(back.labels_, m.labels_)


def test_auto_picks_exact_for_small_data_and_hsgp_for_large(monkeypatch):
    frames = dpgp.datasets.synthetic("highway", n_frames=20, seed=1)
    kw = dict(iterations=1, noise_var=1.0, length_scale_prior=(10.0, 1.0), progress=False)
    assert dpgp.DPGP(**kw).fit(frames).likelihood_ == "exact"
    # exact made costly: the cost model (dpgp.engine_cost) picks hsgp
    monkeypatch.setitem(dpgp.model.engine_cost.COEFFICIENTS, "exact", (1.0, 1.0, 1.0))
    assert dpgp.DPGP(**kw).fit(frames).likelihood_ == "hsgp"
    # a budget too small for exact's largest pattern also picks hsgp, even where exact is cheap
    monkeypatch.setitem(dpgp.model.engine_cost.COEFFICIENTS, "exact", (0.0, 0.0, 0.0))
    frames = dpgp.datasets.synthetic("highway", n_frames=400, seed=1)  # ~4,800 points, 3 patterns
    m = dpgp.DPGP(memory_budget="50MB", **kw).fit(frames)
    assert m.likelihood_ == "hsgp" and m.engine_choice_["exact_fits"] is False


def test_large_fit_is_the_same_with_one_or_two_threads():
    """Past 1,000 frames the informed initialisation places frames by cheap score and builds
    each pattern in one go (in parallel over patterns): still a function of the seed alone."""
    frames = dpgp.datasets.synthetic("highway", n_frames=1200, seed=3)
    kw = dict(iterations=2, likelihood="hsgp", noise_var=1.0, length_scale_prior=(10.0, 1.0), seed=5, progress=False)
    a, b = (dpgp.DPGP(n_threads=t, **kw).fit(frames) for t in (1, 2))
    np.testing.assert_array_equal(a.labels_, b.labels_)
    assert a.history_["log_joint"] == b.history_["log_joint"]
    np.testing.assert_array_equal(a.length_scales_, b.length_scales_)
    assert dpgp.adjusted_rand_index(a.labels_, frames.labels) >= 0.9
