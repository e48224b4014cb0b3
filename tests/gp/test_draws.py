"""Posterior-averaged scores (dpgp.posterior) against an independent numpy computation: each kept
state's mixture density from the GP oracle, averaged in log-sum-exp form; the thinning's memory
bound; model-file round trip; determinism; resuming."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import logsumexp

import dpgp
from dpgp import GPParams
from dpgp.gp.draws import Draws, thin_for, used

from gp_oracle import log_marginal_likelihood as ref_lml
from gp_oracle import log_predictive as ref_pred

WS = (6.0, 9.0)


@pytest.fixture(scope="module")
def data():
    return dpgp.datasets.synthetic("intersection", n_frames=40, seed=2), dpgp.datasets.synthetic(
        "intersection", n_frames=6, seed=9
    )


def _fit(train, **kw):
    settings = dict(iterations=8, noise_var=(0.5, 0.5), length_scale_prior=(10.0, 1.0), alpha=None, seed=3,
                    progress=False, posterior_draws=8, likelihood="exact")  # fmt: skip
    return dpgp.DPGP(**{**settings, **kw}).fit(train)


def _states(model):
    """(labels, length scales, α, noise pair) of every state the averaged scores use: kept draws
    after burn-in, then the final state."""
    d = model.draws_
    out = [
        (d.labels[i].astype(np.int64), d.length_scales[i], d.alpha[i], d.noise_var[i]) for i in used(d, model.n_iter_)
    ]
    return out + [(model.labels_, model.length_scales_, model.alpha_, tuple(model.noise_var_))]


def _oracle_terms(model, train, test, labels, ls, alpha, noise, new_terms):
    """(frames, K+1): log DP weight + log likelihood of each of the state's patterns and of a new one."""
    n = len(train)
    rows = []
    for i, f in enumerate(test):
        terms = []
        for k in range(len(ls)):
            members = train[np.flatnonzero(labels == k)]
            p = GPParams(tuple(ls[k]), model.params_.signal_var, noise, model.params_.mean)
            terms.append(np.log(len(members) / (n + alpha)) + ref_pred(members.xy, members.v, f.xy, f.v, p))
        terms.append(np.log(alpha / (n + alpha)) + new_terms[i])
        rows.append(terms)
    return np.array(rows)


def _oracle(model, train, test, new_terms):
    """Averaged log density and pattern probabilities (over the final state's patterns), by the
    formulas of dpgp.posterior's docstring."""
    states = _states(model)
    blocks = []
    for labels, ls, alpha, noise in states:
        new = new_terms(noise) if callable(new_terms) else new_terms
        terms = _oracle_terms(model, train, test, labels, ls, alpha, noise, new)
        overlap = np.zeros((len(ls) + 1, model.n_patterns_ + 1))
        for j in range(len(ls)):
            for k in range(model.n_patterns_):
                overlap[j, k] = np.mean(model.labels_[labels == j] == k)
        overlap[-1, -1] = 1
        blocks.append((terms, overlap))
    log_density = logsumexp([logsumexp(t, axis=1) for t, _ in blocks], axis=0) - np.log(len(blocks))
    joint = logsumexp(np.concatenate([t for t, _ in blocks], axis=1), axis=1)
    proba = sum(np.exp(t - joint[:, None]) @ o for t, o in blocks)
    return log_density, proba


def test_averaged_scores_match_the_oracle_with_fixed_length_scales(data):
    train, test = data
    model = _fit(train, length_scales=WS)
    assert len(_states(model)) >= 3 and len({len(s[1]) for s in _states(model)} | {0}) >= 2
    p = GPParams(WS, model.params_.signal_var, model.noise_var_, model.params_.mean)
    new = [ref_lml(f.xy, f.v, p) for f in test]  # fixed w: a new pattern's density is the prior's
    want_density, want_proba = _oracle(model, train, test, new)
    got = model.score_samples(test, positions=False, average=True)
    np.testing.assert_allclose(got, want_density, rtol=1e-9)
    np.testing.assert_allclose(model.predict_proba(test, average=True), want_proba, rtol=1e-7, atol=1e-12)
    # the average differs from the last state's score (else the test could not fail)
    assert np.max(np.abs(got - model.score_samples(test, positions=False))) > 1e-6
    # with positions, the φ and ψ terms are added as for the last state
    np.testing.assert_allclose(
        model.score_samples(test, average=True) - got,
        model.score_samples(test) - model.score_samples(test, positions=False), rtol=1e-9,
    )  # fmt: skip


def test_averaged_scores_use_each_draws_own_sampled_noise(data, tmp_path):
    """With the noise sampled in the chain, each kept draw is scored with its own noise pair."""
    train, test = data
    model = _fit(train, length_scales=WS, noise_var="global", iterations=12)
    states = _states(model)
    assert len(states) >= 3 and len({s[3] for s in states}) >= 2  # the noise differs between draws

    def new(noise):  # fixed w: a new pattern's density is the prior's, under the state's noise
        p = GPParams(WS, model.params_.signal_var, noise, model.params_.mean)
        return [ref_lml(f.xy, f.v, p) for f in test]

    want_density, want_proba = _oracle(model, train, test, new)
    np.testing.assert_allclose(model.score_samples(test, positions=False, average=True), want_density, rtol=1e-9)
    np.testing.assert_allclose(model.predict_proba(test, average=True), want_proba, rtol=1e-7, atol=1e-12)
    model.save(tmp_path / "m.npz")
    back = dpgp.DPGP.load(tmp_path / "m.npz")  # the draws' noise survives a model file
    np.testing.assert_allclose(back.score_samples(test, positions=False, average=True), want_density, rtol=1e-9)


def test_averaged_scores_match_the_oracle_with_sampled_length_scales(data):
    train, test = data
    model = _fit(train)
    states = _states(model)
    assert not all(np.array_equal(states[0][1], s[1]) for s in states[1:])  # length scales differ per draw
    # The new-pattern term averages the prior over Algorithm 8's auxiliary length scales, which
    # depend on the frame and the seed only: the same in every state. Take it from the core.
    _, new = model._fitted().log_scores(test)
    want_density, want_proba = _oracle(model, train, test, new)
    np.testing.assert_allclose(model.score_samples(test, positions=False, average=True), want_density, rtol=1e-9)
    np.testing.assert_allclose(model.predict_proba(test, average=True), want_proba, rtol=1e-7, atol=1e-12)


def test_one_state_is_the_last_states_score(data):
    train, test = data
    model = _fit(train, posterior_draws=0)
    assert len(model.draws_) == 0
    np.testing.assert_allclose(model.score_samples(test, average=True), model.score_samples(test), rtol=1e-12)
    np.testing.assert_allclose(
        model.predict_proba(test, average=True), model.predict_proba(test), rtol=1e-9, atol=1e-15
    )


def test_thinning_keeps_a_function_of_the_sweep_count_within_the_bound():
    n_frames, bound = 50, 16
    d = Draws(n_frames)
    for t in range(1, 1001):
        d.record(t, lambda t=t: (np.full(n_frames, 0), np.ones((1, 2)) * t, 1.0, (0.5, 0.5), None), bound)
        assert len(d) <= bound
        step = thin_for(t, bound)
        assert d.sweeps == list(range(step, t + 1, step))
    assert thin_for(1000, bound) == 64 and len(d) == 15
    assert d.nbytes <= bound * (4 * n_frames + 16 * 1 + 16)
    assert all(ls[0, 0] == s for s, ls in zip(d.sweeps, d.length_scales))  # each draw's own state
    assert thin_for(10, 0) == 0


def test_the_fit_keeps_at_most_posterior_draws(data):
    train, _ = data
    model = _fit(train, iterations=20, posterior_draws=4)
    assert model.draws_.sweeps == [8, 16]  # thin_for(20, 4) = 8
    assert len(model.draws_) <= 4
    with pytest.raises(dpgp.InvalidInputError, match="posterior_draws"):
        dpgp.DPGP(posterior_draws=-1).fit(train)


def test_model_file_round_trip_and_old_files(data, tmp_path):
    train, test = data
    model = _fit(train)
    model.save(tmp_path / "m.npz")
    back = dpgp.DPGP.load(tmp_path / "m.npz")
    assert back.draws_.sweeps == model.draws_.sweeps
    for a, b in zip(back.draws_.labels, model.draws_.labels):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(back.score_samples(test, average=True), model.score_samples(test, average=True))
    # a file written before posterior draws: loads, averages over its final state alone
    arrays = dict(np.load(tmp_path / "m.npz"))
    old = {k: v for k, v in arrays.items() if not k.startswith("draw_")}
    np.savez(tmp_path / "old.npz", **old)
    prior = dpgp.DPGP.load(tmp_path / "old.npz")
    assert getattr(prior, "draws_", None) is None
    np.testing.assert_array_equal(prior.score_samples(test, average=True), model.score_samples(test))
    assert prior.evaluate(test).states_averaged == 1
    # draws written before the noise was sampled: scored with the model's noise
    np.savez(tmp_path / "nonoise.npz", **{k: v for k, v in arrays.items() if k != "draw_noise_var"})
    nonoise = dpgp.DPGP.load(tmp_path / "nonoise.npz")
    assert len(nonoise.draws_) == len(model.draws_) and all(v is None for v in nonoise.draws_.noise_var)
    np.testing.assert_array_equal(nonoise.score_samples(test, average=True), model.score_samples(test, average=True))
    # damaged draws are a ModelFileError
    bad = dict(arrays, draw_labels=arrays["draw_labels"] + 100)
    np.savez(tmp_path / "bad.npz", **bad)
    with pytest.raises(dpgp.ModelFileError, match="posterior draw"):
        dpgp.DPGP.load(tmp_path / "bad.npz")
    partial = {k: v for k, v in arrays.items() if k != "draw_alpha"}
    np.savez(tmp_path / "partial.npz", **partial)
    with pytest.raises(dpgp.ModelFileError, match="posterior draws need"):
        dpgp.DPGP.load(tmp_path / "partial.npz")


def test_averaged_scores_do_not_depend_on_threads(data):
    train, test = data
    a, b = (_fit(train, n_threads=t, likelihood=lik) for t in (1, 2) for lik in ("hsgp",))
    assert a.draws_.sweeps == b.draws_.sweeps
    np.testing.assert_array_equal(a.score_samples(test, average=True), b.score_samples(test, average=True))
    np.testing.assert_array_equal(a.predict_proba(test, average=True), b.predict_proba(test, average=True))


def test_resumed_chain_keeps_the_same_draws(data, tmp_path):
    train, test = data
    path = tmp_path / "c.npz"
    _fit(train, iterations=6, checkpoint=path, checkpoint_every=3, posterior_draws=3)
    resumed = dpgp.DPGP.resume(path, iterations=14, progress=False)
    straight = _fit(train, iterations=14, checkpoint=tmp_path / "d.npz", checkpoint_every=3, posterior_draws=3)
    assert resumed.draws_.sweeps == straight.draws_.sweeps == [4, 8, 12]
    for a, b in zip(resumed.draws_.labels, straight.draws_.labels):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(resumed.score_samples(test, average=True), straight.score_samples(test, average=True))


def test_evaluate_averages_by_default(data):
    train, test = data
    model = _fit(train)
    ev = model.evaluate(test)
    assert ev.states_averaged == len(_states(model)) > 1
    want = model.score_samples(test, positions=False, average=True).sum() / test.sizes.sum()
    assert ev.table.loc["dpgp", "log_density"] == pytest.approx(want, rel=1e-12)
    last = model.evaluate(test, average=False)
    assert last.states_averaged == 1
    assert last.table.loc["dpgp", "log_density"] == pytest.approx(
        model.score_samples(test, positions=False).sum() / test.sizes.sum()
    )
