"""The sub-cluster sampler (``DPGP(sampler="subcluster")``; docs/inference.md) against the numpy
oracles, and as one estimator with the collapsed sampler:

(a) exactness: on 5 tiny frames (hsgp, 6 basis functions) the chain's partition frequencies match
    the posterior enumerated by sampler_oracle.py, TV ≤ 0.03, with the hyperparameters fixed, with
    each pattern's noise sampled and with each pattern's length scales sampled (both integrated
    out by quadrature in the oracle); each of those posteriors is > 0.03 from the fixed one;
(b) the same chain for 1 and 2 threads; a fit continued by ``warm_start`` equals one fit;
(c) recovery of the synthetic scenes' patterns; starts from one and from many patterns;
(d) the settings that cannot work are clear errors before any work; ``sampler="auto"`` picks the
    collapsed sampler where the sub-cluster one cannot run, and says why;
(e) model files keep the sampler, and a loaded model scores like the fitted one.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import dpgp
from dpgp.exceptions import InvalidInputError
from dpgp.gp import defaults

import sampler_oracle as so

SWEEPS, BURN_IN = 20_000, 1_000


def fit_tiny(p, alpha, **kw):
    frames, _, _ = so.tiny_problem(5)
    settings = dict(
        assignment="gibbs", length_scales=p.length_scales, signal_var=p.signal_var, mean=p.mean,
        noise_var=p.noise_var, alpha=alpha, progress=False, iterations=SWEEPS, store_labels=True,
        likelihood="hsgp", n_basis=(2, 3), sampler="subcluster", split_merge=6, posterior_draws=0,
    )  # fmt: skip
    return dpgp.DPGP(**{**settings, **kw}).fit(frames)


def chain_tv(m, logp) -> float:
    parts = so.set_partitions(5)
    got = so.empirical_partition_probs(m.label_trace_[BURN_IN:], parts)
    return so.total_variation(got, np.exp(logp))


# --- (a) exactness -------------------------------------------------------------------------------
def test_subcluster_chain_matches_the_enumerated_posterior():
    frames, p, alpha = so.tiny_problem(5)
    m = fit_tiny(p, alpha, seed=3)
    assert m.sampler_ == "subcluster" and m.likelihood_ == "hsgp"
    _, logp = so.partition_posterior(frames, dataclasses.replace(p, basis=m.basis_), alpha)
    tv = chain_tv(m, logp)
    print(f"subcluster, hyperparameters fixed: TV {tv:.4f}")
    assert tv <= 0.03
    h = m.history_
    assert sum(h["split_accepted"]) > 1000 and sum(h["merge_accepted"]) > 1000


def test_subcluster_chain_with_per_pattern_noise_matches_its_posterior():
    frames, p, alpha = so.tiny_problem(5)
    m = fit_tiny(p, alpha, seed=4, noise_var="per_pattern")
    q = dataclasses.replace(p, basis=m.basis_)
    _, logp = so.partition_posterior_noise_per_pattern(frames, q, alpha, defaults.NOISE_PRIOR)
    _, fixed = so.partition_posterior(frames, q, alpha)
    tv = chain_tv(m, logp)
    print(f"subcluster, per-pattern noise: TV {tv:.4f}")
    assert tv <= 0.03
    assert so.total_variation(np.exp(logp), np.exp(fixed)) > 0.03  # the check has power


def test_subcluster_chain_with_sampled_length_scales_matches_its_posterior():
    frames, p, alpha = so.tiny_problem(5)
    prior = (10.0, 0.35)
    m = fit_tiny(p, alpha, seed=5, length_scales=None, length_scale_prior=prior)
    q = dataclasses.replace(p, basis=m.basis_)
    _, logp = so.partition_posterior_length_scales(frames, q, alpha, prior)
    _, fixed = so.partition_posterior(frames, q, alpha)
    tv = chain_tv(m, logp)
    print(f"subcluster, sampled length scales: TV {tv:.4f}")
    assert tv <= 0.03
    assert so.total_variation(np.exp(logp), np.exp(fixed)) > 0.03


# --- (b) reproducible ----------------------------------------------------------------------------
def test_the_chain_is_the_same_for_any_thread_count_and_when_continued():
    frames = dpgp.datasets.synthetic("intersection", n_frames=150, seed=6)
    kw = dict(sampler="subcluster", seed=2, progress=False, store_labels=True)
    one = dpgp.DPGP(iterations=15, n_threads=1, **kw).fit(frames)
    two = dpgp.DPGP(iterations=15, n_threads=2, **kw).fit(frames)
    np.testing.assert_array_equal(one.label_trace_, two.label_trace_)
    assert one.history_["log_joint"] == two.history_["log_joint"]
    # continued at the canonical rebuilds' cadence (checkpoint_every = 10), as for the collapsed sampler
    part = dpgp.DPGP(iterations=10, n_threads=2, **kw).fit(frames)
    part.set_params(iterations=5).fit(frames, warm_start=True)
    np.testing.assert_array_equal(part.label_trace_, one.label_trace_)
    assert part.history_["log_joint"] == one.history_["log_joint"]


# --- (c) recovery and starts ---------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["highway", "intersection"])
def test_recovers_the_synthetic_patterns(kind):
    frames = dpgp.datasets.synthetic(kind, n_frames=400, seed=1)
    m = dpgp.DPGP(iterations=30, sampler="subcluster", seed=0, progress=False).fit(frames)
    ari = dpgp.adjusted_rand_index(frames.labels, m.labels_)
    print(f"{kind}: K {m.n_patterns_}, ARI {ari:.3f}")
    assert ari >= 0.9


@pytest.mark.parametrize("init,k0", [("one", 1), ("many", 60)])
def test_starts_from_one_or_many_patterns(init, k0):
    frames = dpgp.datasets.synthetic("intersection", n_frames=60, seed=2)
    m = dpgp.DPGP(iterations=0, sampler="subcluster", init=init, progress=False).fit(frames)
    assert m.n_patterns_ == k0


# --- (d) settings ----------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "settings,words",
    [
        (dict(sampler="subcluster", likelihood="exact"), "hsgp"),
        (dict(sampler="subcluster", dynamics="sticky"), "sticky"),
        (dict(sampler="subcluster", pattern_moments=True), "pattern_moments"),
        (dict(sampler="gibbs"), "sampler must be one of"),
        (dict(init="random"), "init must be one of"),
    ],
)
def test_what_cannot_work_is_a_clear_error_before_any_work(settings, words):
    frames = dpgp.datasets.synthetic("intersection", n_frames=20, seed=1)
    with pytest.raises(InvalidInputError, match=words):
        dpgp.DPGP(progress=False, **settings).fit(frames)


def test_auto_runs_the_subcluster_sampler_on_hsgp_and_says_why():
    frames = dpgp.datasets.synthetic("intersection", n_frames=60, seed=2)
    m = dpgp.DPGP(iterations=2, likelihood="hsgp", progress=False).fit(frames)
    assert m.sampler_ == "subcluster"
    assert "sub-cluster" in m.engine_choice_["sampler"]["why"]
    exact = dpgp.DPGP(iterations=2, likelihood="exact", progress=False).fit(frames)
    assert exact.sampler_ == "collapsed" and "exact" in exact.engine_choice_["sampler"]["why"]
    sticky = dpgp.DPGP(iterations=2, likelihood="hsgp", dynamics="sticky", progress=False).fit(frames)
    assert sticky.sampler_ == "collapsed"


@pytest.mark.parametrize("n_frames,engine", [(60, "exact"), (150, "hsgp")])
def test_likelihood_auto_keeps_the_sampler_and_its_reason_once_the_engine_is_settled(n_frames, engine):
    # Both decided after hsgp's initialisation (the second step of likelihood="auto").
    frames = dpgp.datasets.synthetic("highway", n_frames=n_frames, seed=2)
    m = dpgp.DPGP(iterations=1, progress=False).fit(frames)
    assert m.likelihood_ == engine and m.engine_choice_["sizes_from"] == "hsgp initialisation"
    want = "subcluster" if engine == "hsgp" else "collapsed"
    assert m.sampler_ == want and m.engine_choice_["sampler"]["sampler"] == want


# --- (e) model files -------------------------------------------------------------------------------
def test_a_saved_subcluster_model_loads_and_scores_the_same(tmp_path):
    frames = dpgp.datasets.synthetic("intersection", n_frames=120, seed=3)
    train, test = frames[:100], frames[100:]
    m = dpgp.DPGP(iterations=8, sampler="subcluster", seed=1, progress=False).fit(train)
    m.save(tmp_path / "m.npz")
    back = dpgp.DPGP.load(tmp_path / "m.npz")
    assert back.sampler_ == "subcluster" and back.engine_info()["sampler"] == "subcluster"
    np.testing.assert_array_equal(back.labels_, m.labels_)
    np.testing.assert_allclose(back.score_samples(test), m.score_samples(test), rtol=1e-12)
    mean, _ = back.velocity_field(0, [[0.0, 0.0]])
    np.testing.assert_allclose(mean, m.velocity_field(0, [[0.0, 0.0]])[0])
