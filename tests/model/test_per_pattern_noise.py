"""Per-pattern noise (``noise_var="per_pattern"``; docs/inference.md) against the numpy oracles:

(a) Gibbs + split–merge on 5 tiny frames matches the enumerated partition posterior with each
    pattern's noise integrated out under its prior (sampler_oracle.py), TV ≤ 0.03, exact and
    hsgp; that posterior is > 0.03 from the global-noise one, and so is the chain;
(b) scores use each pattern's own noise: the existing patterns' terms equal gp_oracle's
    predictive with that pattern's pair; the model file, the posterior draws and a resumed
    checkpoint keep the pairs; the chain is the same on 1 and 2 threads and in other units.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import dpgp
from dpgp.gp import defaults

import gp_oracle
import sampler_oracle as so

SWEEPS, BURN_IN = 20_000, 1_000


def fit_tiny(p, alpha, **kw):
    frames, _, _ = so.tiny_problem(5)
    settings = dict(
        assignment="gibbs", length_scales=p.length_scales, signal_var=p.signal_var, mean=p.mean,
        alpha=alpha, progress=False, iterations=SWEEPS, store_labels=True, n_basis=(2, 3),
        noise_var="per_pattern", split_merge=2, posterior_draws=0, sampler="collapsed",
    )  # fmt: skip
    return dpgp.DPGP(**{**settings, **kw}).fit(frames)


@pytest.mark.parametrize("likelihood,proposal", [("exact", "informed"), ("hsgp", "full")])
def test_per_pattern_noise_chain_matches_the_posterior_with_each_patterns_noise_integrated(likelihood, proposal):
    frames, p, alpha = so.tiny_problem(5)
    m = fit_tiny(p, alpha, seed=21, likelihood=likelihood, proposal=proposal)
    assert m.defaults_.noise_var_source == "per_pattern"
    q = p if m.likelihood_ == "exact" else dataclasses.replace(p, basis=m.basis_)
    parts, logp = so.partition_posterior_noise_per_pattern(frames, q, alpha, defaults.NOISE_PRIOR)
    _, global_logp = so.partition_posterior_noise_summed(frames, q, alpha, defaults.NOISE_PRIOR)
    got = so.empirical_partition_probs(m.label_trace_[BURN_IN:], parts)
    tv = so.total_variation(got, np.exp(logp))
    tv_global = so.total_variation(got, np.exp(global_logp))
    gap = so.total_variation(np.exp(logp), np.exp(global_logp))
    print(
        f"{likelihood}/{proposal}, per-pattern noise: TV {tv:.4f} (chain to the global-noise posterior {tv_global:.4f}; posteriors {gap:.4f} apart)"
    )
    assert tv <= 0.03
    # Power: a sampler that ignored the per-pattern noise (global pair) would be this far off.
    assert gap > 0.03 and tv_global > 0.03
    assert m.pattern_noise_var_.shape == (m.n_patterns_, 2)


def test_scores_use_each_patterns_own_noise():
    frames = dpgp.datasets.synthetic("intersection", n_frames=40, seed=3)
    train, test = frames[:30], frames[30:]
    m = dpgp.DPGP(iterations=5, seed=4, progress=False, likelihood="exact", noise_var="per_pattern").fit(train)
    noise = m.pattern_noise_var_
    assert m.n_patterns_ >= 2 and len(np.unique(noise[:, 0])) == m.n_patterns_  # each its own
    terms = m._log_joint_terms(test)
    n = len(m.labels_)
    for k in range(m.n_patterns_):
        members = np.flatnonzero(m.labels_ == k)
        rows = np.concatenate([np.arange(train.offsets[j], train.offsets[j + 1]) for j in members])
        pk = so.Params(tuple(m.length_scales_[k]), m.params_.signal_var, tuple(noise[k]), m.params_.mean)
        for t, f in enumerate(test):
            want = gp_oracle.log_predictive(train.xy[rows], train.v[rows], f.xy, f.v, pk)
            want += np.log(len(members)) - np.log(n + m.alpha_)
            assert terms[t, k] == pytest.approx(want, rel=1e-9, abs=1e-9)
    # the history's pair is the frame-weighted median of the patterns' pairs
    assert m.noise_var_ == (m.history_["noise_var_x"][-1], m.history_["noise_var_y"][-1])
    w = np.bincount(m.labels_)
    for d in range(2):
        order = np.argsort(noise[:, d], kind="stable")
        j = np.searchsorted(np.cumsum(w[order]), 0.5 * w.sum())
        assert m.noise_var_[d] == noise[order[j], d]
    assert "noise variance per pattern" in m.summary()


def test_model_file_draws_and_checkpoint_keep_the_pairs(tmp_path):
    frames = dpgp.datasets.synthetic("intersection", n_frames=50, seed=6)
    train, test = frames[:40], frames[40:]
    kw = dict(seed=2, progress=False, noise_var="per_pattern", split_merge=3, store_labels=True)
    m = dpgp.DPGP(iterations=8, **kw).fit(train)
    m.save(tmp_path / "m.npz")
    back = dpgp.DPGP.load(tmp_path / "m.npz")
    np.testing.assert_array_equal(back.pattern_noise_var_, m.pattern_noise_var_)
    np.testing.assert_array_equal(back.score_samples(test), m.score_samples(test))
    np.testing.assert_array_equal(back.score_samples(test, average=True), m.score_samples(test, average=True))
    assert any(isinstance(v, np.ndarray) for v in m.draws_.noise_var)
    # a draw scored with the global pair would differ: the averaged score uses the draws' pairs
    assert back.draws_.noise_var[-1].shape[1] == 2
    # a resumed chain continues bitwise
    ck = tmp_path / "ck.npz"
    full = dpgp.DPGP(iterations=8, checkpoint_every=3, **kw).fit(train)
    part = dpgp.DPGP(iterations=5, checkpoint_every=3, checkpoint=ck, **kw).fit(train)
    assert part.n_iter_ == 5
    resumed = dpgp.DPGP.resume(ck, iterations=8)
    np.testing.assert_array_equal(resumed.label_trace_, full.label_trace_)
    np.testing.assert_array_equal(resumed.pattern_noise_var_, full.pattern_noise_var_)
    assert resumed.history_["noise_var_x"] == full.history_["noise_var_x"]


def test_same_chain_with_one_or_two_threads_and_in_other_units():
    frames = dpgp.datasets.synthetic("intersection", n_frames=60, seed=5)
    kw = dict(iterations=5, seed=3, progress=False, store_labels=True, split_merge=5, noise_var="per_pattern")
    a, b = (dpgp.DPGP(n_threads=t, **kw).fit(frames) for t in (1, 2))
    np.testing.assert_array_equal(a.label_trace_, b.label_trace_)
    np.testing.assert_array_equal(a.pattern_noise_var_, b.pattern_noise_var_)
    c = 0.3048
    metres = dpgp.Frames(frames.ids, frames.offsets, frames.xy * c, frames.v * c, frames.labels)
    m = dpgp.DPGP(n_threads=1, **kw).fit(metres)
    np.testing.assert_array_equal(m.label_trace_, a.label_trace_)
    np.testing.assert_allclose(m.pattern_noise_var_, a.pattern_noise_var_ * c**2, rtol=1e-6)


def test_fit_chains_passes_it_through():
    frames = dpgp.datasets.synthetic("intersection", n_frames=40, seed=7)
    ch = dpgp.fit_chains(frames, n_chains=2, iterations=4, n_workers=1, seed=1, noise_var="per_pattern", progress=False)
    best = ch.best_model()
    assert best.defaults_.noise_var_source == "per_pattern"
    assert best.pattern_noise_var_.shape == (best.n_patterns_, 2)
