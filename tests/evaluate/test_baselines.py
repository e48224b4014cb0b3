"""The closed-form density baselines (dpgp.evaluate.baselines): the constant-velocity density
against scipy on small frames with first appearances, its spread against a numerical maximum of
the likelihood, the position-blind fallback, and the error paths."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import optimize, stats

import dpgp
from dpgp.evaluate import baselines


def small_frames(seed: int, n_frames: int = 6, first: float = 0.3, tilt: float = 0.6) -> dpgp.Frames:
    """Frames of 1-4 vehicles whose velocity changes are correlated in x and y (along a road at
    ``tilt`` radians); a share ``first`` of the vehicles has no previous velocity."""
    rng = np.random.default_rng(seed)
    rows = []
    along = np.array([np.cos(tilt), np.sin(tilt)])
    for f in range(n_frames):
        for _ in range(rng.integers(1, 5)):
            prev = rng.normal([6.0, 4.0], 2.0)
            v = prev + along * rng.normal(0, 1.5) + rng.normal(0, 0.3, 2)
            if rng.random() < first:
                prev = np.full(2, np.nan)
            rows.append((f, *rng.uniform(-20, 20, 2), *v, *prev))
    a = np.array(rows)
    return dpgp.Frames.from_arrays(a[:, 0], *a[:, 1:5].T, prev_vx=a[:, 5], prev_vy=a[:, 6])


def oracle_cov(train: dpgp.Frames) -> np.ndarray:
    """The ML covariance of v − prev_v with the mean fixed at zero, as a loop of outer products."""
    total, n = np.zeros((2, 2)), 0
    for f in train:
        for v, p in zip(f.v, f.prev_v):
            if np.isnan(p).any():
                continue
            total += np.outer(v - p, v - p)
            n += 1
    return total / n


def oracle_scores(train: dpgp.Frames, test: dpgp.Frames) -> list[float]:
    """Per test frame, with scipy: the vehicles' log densities, N(v; prev_v, Σ) where a previous
    velocity is known, else the position-blind Gaussians of the training velocities."""
    cov = oracle_cov(train)
    mu, sd = train.v.mean(axis=0), train.v.std(axis=0)
    out = []
    for f in test:
        total = 0.0
        for v, p in zip(f.v, f.prev_v):
            if np.isnan(p).any():
                total += stats.norm.logpdf(v, mu, sd).sum()
            else:
                total += stats.multivariate_normal.logpdf(v, mean=p, cov=cov)
        out.append(total)
    return out


def test_constant_velocity_scores_match_scipy_with_first_appearances():
    train, test = small_frames(1, n_frames=30), small_frames(2, n_frames=8, first=0.4)
    has = ~np.isnan(test.prev_v[:, 0])
    assert 0 < has.sum() < test.n_points  # both kinds of vehicle are scored
    got = baselines.constant_velocity_scores(train, test)
    np.testing.assert_allclose(got, oracle_scores(train, test), rtol=1e-12)
    assert got.shape == (len(test),)
    # the re-export is the same function, and the fitted object scores the same
    assert dpgp.evaluate.constant_velocity_scores is baselines.constant_velocity_scores
    np.testing.assert_allclose(dpgp.evaluate.ConstantVelocity.fit(train).score_frames(test), got, rtol=0)


def test_fallback_rows_score_as_the_position_blind_baseline():
    train = small_frames(3, n_frames=20)
    test = small_frames(4, n_frames=5, first=1.0)  # no previous velocities at all in the test frames
    assert np.isnan(test.prev_v).all()
    np.testing.assert_allclose(
        baselines.constant_velocity_scores(train, test), baselines.position_blind_scores(train, test), rtol=1e-13
    )


def test_the_spread_is_the_maximum_likelihood_estimate():
    train = small_frames(5, n_frames=25)
    fit = baselines.ConstantVelocity.fit(train)
    np.testing.assert_allclose(fit.cov, oracle_cov(train), rtol=1e-12)
    assert abs(fit.cov[0, 1]) > 0.1 * np.sqrt(fit.cov[0, 0] * fit.cov[1, 1])  # the data are correlated
    has = ~np.isnan(train.prev_v[:, 0])
    assert fit.n_steps == has.sum()
    np.testing.assert_allclose(fit.blind_mean, train.v.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(fit.blind_var, train.v.var(axis=0), rtol=1e-12)
    # independently: maximise the training steps' likelihood numerically over Cholesky factors
    r = train.v[has] - train.prev_v[has]

    def neg(theta):
        chol = np.array([[np.exp(theta[0]), 0.0], [theta[1], np.exp(theta[2])]])
        return -stats.multivariate_normal.logpdf(r, mean=np.zeros(2), cov=chol @ chol.T).sum()

    best = optimize.minimize(neg, np.zeros(3), method="Nelder-Mead", options={"xatol": 1e-10, "fatol": 1e-12})
    chol = np.array([[np.exp(best.x[0]), 0.0], [best.x[1], np.exp(best.x[2])]])
    np.testing.assert_allclose(fit.cov, chol @ chol.T, rtol=1e-4, atol=1e-6)
    assert -neg(_chol_params(fit.cov)) >= -best.fun - 1e-9


def _chol_params(cov: np.ndarray) -> np.ndarray:
    chol = np.linalg.cholesky(cov)
    return np.array([np.log(chol[0, 0]), chol[1, 0], np.log(chol[1, 1])])


def test_frames_without_previous_velocities_raise_a_typed_error():
    with_prev = small_frames(6)
    without = dpgp.Frames(with_prev.ids, with_prev.offsets, with_prev.xy, with_prev.v)
    for train, test, which in ((without, with_prev, "training"), (with_prev, without, "test")):
        with pytest.raises(
            dpgp.InvalidInputError, match=f"the {which} frames carry no previous velocities.*make_frames"
        ):
            baselines.constant_velocity_scores(train, test)


def test_no_previous_step_or_no_spread_raise_typed_errors():
    f = small_frames(7, n_frames=10)
    firsts = small_frames(7, n_frames=10, first=1.0)
    with pytest.raises(dpgp.InvalidInputError, match="no training vehicle has a previous velocity"):
        baselines.constant_velocity_scores(firsts, f)
    # every step keeps its velocity: Σ = 0
    same = dpgp.Frames(f.ids, f.offsets, f.xy, f.v, prev_v=f.v.copy())
    with pytest.raises(dpgp.InvalidInputError, match="no spread"):
        baselines.ConstantVelocity.fit(same)
    # changes only along one line: Σ singular
    line = dpgp.Frames(f.ids, f.offsets, f.xy, f.v, prev_v=f.v - np.outer(np.arange(f.n_points), [1.0, 2.0]))
    with pytest.raises(dpgp.InvalidInputError, match="no spread"):
        baselines.ConstantVelocity.fit(line)
