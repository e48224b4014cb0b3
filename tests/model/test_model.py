"""The fitted model's predictive quantities against the numpy oracle, and estimator conventions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import logsumexp

import dpgp
from dpgp import GPParams

from distributions_oracle import smoothed_oracle
from gp_oracle import log_marginal_likelihood as ref_lml
from gp_oracle import log_predictive as ref_pred

WS = (6.0, 9.0)


@pytest.fixture(scope="module")
def fitted():
    train = dpgp.datasets.synthetic("intersection", n_frames=60, seed=2)
    test = dpgp.datasets.synthetic("intersection", n_frames=6, seed=9)
    # one noise pair for all patterns: the formulas below use it (per-pattern noise has its own
    # oracle test, tests/model/test_per_pattern_noise.py)
    model = dpgp.DPGP(iterations=4, length_scales=WS, seed=0, progress=False, noise_var="global").fit(train)
    return model, train, test


def oracle_terms(model, train, test):
    """(frames, K+1) log prior weight + log likelihood, from the formulas."""
    p = GPParams(WS, tuple(train.v.var(axis=0)), model.noise_var_, tuple(train.v.mean(axis=0)))
    n, a = len(train), model.alpha_
    rows = []
    for f in test:
        terms = []
        for k in range(model.n_patterns_):
            members = train[np.flatnonzero(model.labels_ == k)]
            terms.append(np.log(len(members) / (n + a)) + ref_pred(members.xy, members.v, f.xy, f.v, p))
        terms.append(np.log(a / (n + a)) + ref_lml(f.xy, f.v, p))  # fixed w: Algorithm 8's mass
        rows.append(terms)
    return np.array(rows)


def test_predict_proba_and_score_samples_match_the_formulas(fitted):
    model, train, test = fitted
    terms = oracle_terms(model, train, test)
    want_p = np.exp(terms - logsumexp(terms, axis=1, keepdims=True))
    np.testing.assert_allclose(model.predict_proba(test), want_p, rtol=1e-8, atol=1e-12)
    np.testing.assert_array_equal(model.predict(test), np.argmax(terms[:, :-1], axis=1))
    velocity_part = logsumexp(terms, axis=1)
    np.testing.assert_allclose(model.score_samples(test, positions=False), velocity_part, rtol=1e-9)
    full = model.score_samples(test)
    np.testing.assert_allclose(full - velocity_part, positions_oracle(model, train, test), rtol=1e-9)


def positions_oracle(model, train, frames):
    """log φ̃(l) + Σ log ψ̃ of each frame, from the formulas, with the model's pseudo-counts over
    the training frames' bounding box on the model's 20 x 20 grid."""
    d = dpgp.generate.scenarios.distributions(model)
    assert d.roi == train.bounds() and d.bins == (20, 20)
    log_phi, log_psi = smoothed_oracle(train.sizes, train.xy, train.bounds(), (20, 20), *d.pseudocount)
    return [log_phi(len(f)) + sum(log_psi(x, y) for x, y in f.xy) for f in frames]


def test_score_samples_is_finite_for_a_count_or_position_never_seen(fitted):
    """A held-out frame with more vehicles than any training frame, or a vehicle half a bin
    beyond the training ROI, scores finitely (the paper's φ, ψ give it 0): its positions term is
    the smoothed φ̃ and ψ̃ of the training frames."""
    model, train, _ = fitted
    crowd = train[int(np.argmax(train.sizes))]
    x0, x1, _, _ = train.bounds()
    beyond = np.array([[x1 + 0.5 * (x1 - x0) / 20, crowd.xy[0, 1]]])
    xy = np.vstack([crowd.xy, crowd.xy[:2] + 0.25, beyond])
    v = np.vstack([crowd.v, crowd.v[:3]])
    frame = dpgp.Frames.from_arrays(np.zeros(len(xy)), xy[:, 0], xy[:, 1], v[:, 0], v[:, 1])
    d = dpgp.generate.scenarios.distributions(model)
    paper = dpgp.EmpiricalDistributions(d.count_hist, d.position_hist, d.roi, pseudocount=0)
    assert len(xy) > d.max_count and paper.log_frame_density(xy) == -np.inf
    got = model.score_samples(frame)[0]
    assert np.isfinite(got)
    assert got - model.score_samples(frame, positions=False)[0] == pytest.approx(
        positions_oracle(model, train, frame)[0]
    )


def test_velocity_field_matches_the_gp_posterior(fitted):
    model, train, _ = fitted
    p = GPParams(WS, tuple(train.v.var(axis=0)), model.noise_var_, tuple(train.v.mean(axis=0)))
    members = train[np.flatnonzero(model.labels_ == 1)]
    q = np.random.default_rng(0).uniform(-50, 50, (200, 2))
    mean, var = model.velocity_field(1, q)
    ref_mean, ref_var = dpgp.gp.posterior(members.xy, members.v, q, p)
    np.testing.assert_allclose(mean, ref_mean, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(var, ref_var, rtol=1e-9, atol=1e-9)


def test_estimator_conventions_and_errors(fitted):
    model, train, _ = fitted
    assert model.get_params()["length_scales"] == WS
    assert "length_scales=(6.0, 9.0)" in repr(model)
    with pytest.raises(dpgp.NotFittedError):
        dpgp.DPGP().predict(train)
    with pytest.raises(dpgp.InvalidInputError, match="assignment must be one of"):
        dpgp.DPGP(assignment="greedy").fit(train)
    with pytest.raises(dpgp.InvalidInputError, match="length_scale_fraction"):
        dpgp.DPGP(length_scale_fraction=0.0, progress=False).fit(train)
    with pytest.raises(dpgp.InvalidInputError, match="pattern 99 does not exist"):
        model.velocity_field(99, [[0.0, 0.0]])
    with pytest.raises(dpgp.InvalidInputError, match="unknown parameter"):
        dpgp.DPGP().set_params(iters=3)


def test_length_scale_fraction_keeps_the_chain_valid_and_deterministic():
    frames = dpgp.datasets.synthetic("highway", n_frames=80, seed=4)
    a, b = (
        dpgp.DPGP(iterations=6, length_scale_fraction=0.3, seed=1, n_threads=t, progress=False).fit(frames)
        for t in (1, 2)
    )
    np.testing.assert_array_equal(a.labels_, b.labels_)
    assert a.history_["log_joint"] == b.history_["log_joint"]
    assert dpgp.adjusted_rand_index(a.labels_, frames.labels) >= 0.9


def test_pattern_moments_option_uses_each_patterns_own_mean_and_variance():
    frames = dpgp.datasets.synthetic("intersection", n_frames=60, seed=3)
    # full proposals: after 4 informed sweeps at the true noise level the partition is still
    # split (ARI 0.65), which is about mixing, not about pattern_moments
    m = dpgp.DPGP(iterations=4, pattern_moments=True, seed=0, progress=False, proposal="full").fit(frames)
    assert dpgp.adjusted_rand_index(m.labels_, frames.labels) >= 0.9
    for k in range(m.n_patterns_):
        members = frames[np.flatnonzero(m.labels_ == k)]
        # far from every vehicle the field reverts to the pattern's own prior mean and variance
        mean, var = m.velocity_field(k, [[1e6, 1e6]])
        np.testing.assert_allclose(mean[0], members.v.mean(axis=0), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(var[0], np.maximum(members.v.var(axis=0), 1e-3 * frames.v.var(axis=0)), rtol=1e-12)
    back = m.get_params()["pattern_moments"]
    assert back is True


def test_pattern_moments_model_round_trips(tmp_path):
    frames = dpgp.datasets.synthetic("highway", n_frames=40, seed=1)
    m = dpgp.DPGP(iterations=2, pattern_moments=True, seed=0, progress=False).fit(frames)
    m.save(tmp_path / "m.npz")
    back = dpgp.DPGP.load(tmp_path / "m.npz")
    assert back.pattern_moments is True
    np.testing.assert_array_equal(back.predict_proba(frames), m.predict_proba(frames))
