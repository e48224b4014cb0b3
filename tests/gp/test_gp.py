"""The Rust GP layer against the numpy/scipy oracle in gp_oracle.py."""

from __future__ import annotations

import numpy as np
import pytest

import dpgp
from dpgp import GPParams

from gp_oracle import log_marginal_likelihood as ref_lml
from gp_oracle import log_predictive as ref_pred
from gp_oracle import posterior as ref_post

RTOL = 1e-9


def random_problem(n: int, seed: int):
    """Points in a highway-like ROI with a smooth field plus noise, and random hyperparameters."""
    rng = np.random.default_rng(seed)
    xy = np.column_stack([rng.uniform(0, 72, n), rng.uniform(0, 400, n)])
    v = np.column_stack([np.sin(xy[:, 1] / 40) + rng.normal(0, 0.5, n), 40 + xy[:, 0] / 6 + rng.normal(0, 1, n)])
    p = GPParams(
        length_scales=(rng.uniform(2, 30), rng.uniform(5, 80)),
        signal_var=(rng.uniform(0.2, 5), rng.uniform(1, 60)),
        noise_var=(rng.uniform(0.05, 2), rng.uniform(0.05, 2)),
        mean=(rng.normal(), rng.uniform(20, 50)),
    )
    return xy, v, p


SIZES = [1, 2, 7, 15, 120, 700, 2000]


@pytest.mark.parametrize("n", SIZES)
def test_log_marginal_likelihood_matches_numpy(n):
    xy, v, p = random_problem(n, seed=n)
    got = dpgp.gp.log_marginal_likelihood(xy, v, p)
    assert got == pytest.approx(ref_lml(xy, v, p), rel=RTOL)


@pytest.mark.parametrize("n", SIZES)
def test_log_predictive_matches_numpy(n):
    xy, v, p = random_problem(n + 15, seed=100 + n)
    tr, te = slice(0, n), slice(n, n + 15)
    got = dpgp.gp.log_predictive(xy[tr], v[tr], xy[te], v[te], p)
    assert got == pytest.approx(ref_pred(xy[tr], v[tr], xy[te], v[te], p), rel=RTOL)


@pytest.mark.parametrize("n", SIZES)
def test_posterior_matches_numpy(n):
    xy, v, p = random_problem(n, seed=200 + n)
    q = np.random.default_rng(n).uniform([-10, -50], [80, 450], size=(1500, 2))
    mean, var = dpgp.gp.posterior(xy, v, q, p)
    ref_mean, ref_var = ref_post(xy, v, q, p)
    np.testing.assert_allclose(mean, ref_mean, rtol=RTOL, atol=RTOL * np.abs(ref_mean).max())
    # Variances near zero are a cancellation s² - k'K⁻¹k in both codes: compare against the prior scale.
    np.testing.assert_allclose(var, ref_var, rtol=RTOL, atol=RTOL * max(p.signal_var))


def test_equal_signal_variances_share_one_factor_and_agree():
    xy, v, p = random_problem(300, seed=7)
    shared = GPParams(p.length_scales, signal_var=3.0, noise_var=p.noise_var[0], mean=p.mean)
    assert dpgp.gp.log_marginal_likelihood(xy, v, shared) == pytest.approx(ref_lml(xy, v, shared), rel=RTOL)
    got = dpgp.gp.log_predictive(xy[:280], v[:280], xy[280:], v[280:], shared)
    assert got == pytest.approx(ref_pred(xy[:280], v[:280], xy[280:], v[280:], shared), rel=RTOL)


def test_equal_signal_and_unequal_noise_use_one_factor_per_output():
    xy, v, p = random_problem(300, seed=8)
    split = GPParams(p.length_scales, signal_var=3.0, noise_var=(0.9, 0.05), mean=p.mean)
    assert dpgp.gp.log_marginal_likelihood(xy, v, split) == pytest.approx(ref_lml(xy, v, split), rel=RTOL)
    got = dpgp.gp.log_predictive(xy[:280], v[:280], xy[280:], v[280:], split)
    assert got == pytest.approx(ref_pred(xy[:280], v[:280], xy[280:], v[280:], split), rel=RTOL)


def test_predictive_equals_ratio_of_marginals():
    xy, v, p = random_problem(215, seed=3)
    lml = dpgp.gp.log_marginal_likelihood
    ratio = lml(xy, v, p) - lml(xy[:200], v[:200], p)
    assert dpgp.gp.log_predictive(xy[:200], v[:200], xy[200:], v[200:], p) == pytest.approx(ratio, rel=1e-9)


def test_real_us101_frames_match_numpy(us101_path):
    frames = dpgp.read_frames(us101_path)
    train, test = frames[:80], frames[80]
    p = GPParams(
        (10.0, 40.0),
        signal_var=(train.v[:, 0].var(), train.v[:, 1].var()),
        noise_var=1.0,
        mean=tuple(train.v.mean(axis=0)),
    )
    assert dpgp.gp.log_marginal_likelihood(train.xy, train.v, p) == pytest.approx(
        ref_lml(train.xy, train.v, p), rel=RTOL
    )
    got = dpgp.gp.log_predictive(train.xy, train.v, test.xy, test.v, p)
    assert got == pytest.approx(ref_pred(train.xy, train.v, test.xy, test.v, p), rel=RTOL)
    mean, var = dpgp.gp.posterior(train.xy, train.v, test.xy, p)
    ref_mean, ref_var = ref_post(train.xy, train.v, test.xy, p)
    np.testing.assert_allclose(mean, ref_mean, rtol=RTOL)
    np.testing.assert_allclose(var, ref_var, rtol=RTOL, atol=RTOL * max(p.signal_var))


def test_real_lankershim_frames_match_numpy(lankershim_path):
    frames = dpgp.read_frames(lankershim_path)
    train, test = frames[:20], frames[20]
    p = GPParams((20.0, 20.0), signal_var=tuple(train.v.var(axis=0)), noise_var=1.0, mean=tuple(train.v.mean(axis=0)))
    got = dpgp.gp.log_predictive(train.xy, train.v, test.xy, test.v, p)
    assert got == pytest.approx(ref_pred(train.xy, train.v, test.xy, test.v, p), rel=RTOL)


@pytest.mark.parametrize("n", [7, 700])
def test_log_predictive_of_a_large_test_set_matches_numpy(n):
    # 300 test points: past the frame-sized kernels, so the faer factorisation of S is used.
    xy, v, p = random_problem(n + 300, seed=300 + n)
    tr, te = slice(0, n), slice(n, n + 300)
    got = dpgp.gp.log_predictive(xy[tr], v[tr], xy[te], v[te], p)
    assert got == pytest.approx(ref_pred(xy[tr], v[tr], xy[te], v[te], p), rel=RTOL)


def test_log_predictive_frames_scores_each_frame_as_log_predictive():
    # Frames of 1 to 1100 points: several blocks of the scoring loop, and one frame larger than a block.
    sizes = [3, 1, 40, 1100, 9, 700, 2]
    xy, v, p = random_problem(200 + sum(sizes), seed=11)
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    txy, tv, sxy, sv = xy[:200], v[:200], xy[200:], v[200:]
    got = dpgp.gp.log_predictive_frames(txy, tv, sxy, sv, offsets, p)
    want = [ref_pred(txy, tv, sxy[a:b], sv[a:b], p) for a, b in zip(offsets[:-1], offsets[1:])]
    np.testing.assert_allclose(got, want, rtol=RTOL)


@pytest.mark.parametrize("offsets", [[0, 2, 2, 5], [0, 3], [1, 5], [0, 6], [0, -1, 5]])
def test_log_predictive_frames_refuses_bad_offsets(offsets):
    xy, v, p = random_problem(10, seed=1)
    with pytest.raises(dpgp.ShapeError):
        dpgp.gp.log_predictive_frames(xy, v, xy[:5], v[:5], offsets, p)
