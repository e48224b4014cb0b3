"""The DP-GP sampler (dpgp.DPGP) against the numpy oracle in sampler_oracle.py:

(a) exactness: with w and α fixed, partition frequencies of a long Gibbs run on 5 tiny frames
    match the posterior enumerated over all 52 partitions (total variation ≤ 0.03);
(b) the collapsed conditional of a frame (existing, own and new pattern) equals the formula;
(c) recovery of the true patterns of dpgp.datasets.synthetic scenes (ARI ≥ 0.9), both modes;
(d) determinism across thread counts, and different chains for different seeds.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

import dpgp

import sampler_oracle as so

SWEEPS, BURN_IN = 20_000, 1_000


def fit_tiny(p: so.Params, alpha: float, **kw) -> dpgp.DPGP:
    frames, _, _ = so.tiny_problem(5)
    settings = dict(
        assignment="gibbs",
        length_scales=p.length_scales,
        signal_var=p.signal_var,
        mean=p.mean,
        noise_var=p.noise_var,
        alpha=alpha,
        progress=False,
    )
    return dpgp.DPGP(**{**settings, **kw}).fit(frames)


# --- (a) exactness ------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [0, 1])
def test_gibbs_partition_frequencies_match_the_enumerated_posterior(seed):
    frames, p, alpha = so.tiny_problem(5)
    t = time.perf_counter()
    m = fit_tiny(p, alpha, iterations=SWEEPS, seed=seed, store_labels=True)
    seconds = time.perf_counter() - t
    trace = m.label_trace_
    assert trace.shape == (SWEEPS, 5)
    assert all(np.array_equal(so.canonical(row), row) for row in trace[:: SWEEPS // 200])
    parts, logp = so.partition_posterior(frames, p, alpha)
    want = np.exp(logp)
    got = so.empirical_partition_probs(trace[BURN_IN:], parts)
    tv = so.total_variation(got, want)
    worst = np.argsort(-np.abs(got - want))[:3]
    detail = ", ".join(f"{parts[j].tolist()}: {got[j]:.4f} vs {want[j]:.4f}" for j in worst)
    print(f"seed {seed}: TV {tv:.4f} over {SWEEPS - BURN_IN} sweeps ({seconds:.1f} s)")
    assert tv <= 0.03, f"TV {tv:.4f} > 0.03; largest gaps (partition: sampled vs exact): {detail}"


# --- (b) conditionals ---------------------------------------------------------------------------
def check_conditionals(m: dpgp.DPGP, frames, p: so.Params, frames_to_check) -> int:
    """Compare m.conditional_log_probs(i) with the oracle at m's state; return how many of the
    checked frames were alone in their pattern (the -inf entry)."""
    alone = 0
    for i in frames_to_check:
        got = np.asarray(m.conditional_log_probs(i))
        want = so.conditional_log_probs(frames, m.labels_, i, p, m.alpha_)
        assert got.shape == (m.n_patterns_ + 1,)
        assert np.array_equal(np.isneginf(got), np.isneginf(want)), f"frame {i}: {got} vs {want}"
        fin = np.isfinite(want)
        np.testing.assert_allclose(got[fin], want[fin], rtol=1e-9, atol=1e-8, err_msg=f"frame {i}, labels {m.labels_}")
        alone += int(np.sum(m.labels_ == m.labels_[i]) == 1)
    return alone


SIGNALS = {"default": None, "equal": (2.0, 2.0), "unequal": (0.5, 3.0), "unequal_noise": (2.0, 2.0)}
# Equal signal variances with unequal noise: the outputs no longer share one factor.
NOISES = {"unequal_noise": (0.6, 1.4)}


@pytest.mark.parametrize("signal", SIGNALS)
def test_conditionals_on_tiny_frames_match_the_formula(signal):
    frames, p0, alpha = so.tiny_problem(5)
    noise = NOISES.get(signal, p0.noise_var)
    p = so.default_params(frames, p0.length_scales, noise, SIGNALS[signal], None if signal == "default" else p0.mean)
    alone = 0
    for seed in range(6):
        m = dpgp.DPGP(
            iterations=3,
            length_scales=p.length_scales,
            signal_var=SIGNALS[signal],
            mean=None if signal == "default" else p.mean,
            noise_var=p.noise_var,
            alpha=0.7,
            seed=seed,
            progress=False,
        ).fit(frames)
        alone += check_conditionals(m, frames, p, range(len(frames)))
    # the posterior puts most of its mass on partitions with a singleton: the -inf case was seen
    assert alone > 0


@pytest.mark.parametrize("signal", SIGNALS)
def test_conditionals_on_a_synthetic_scene_match_the_formula(signal):
    frames = dpgp.datasets.synthetic("intersection", n_frames=40, seed=3)
    ws = (6.0, 8.0)
    m = dpgp.DPGP(
        iterations=3, length_scales=ws, signal_var=SIGNALS[signal], noise_var=1.0, seed=1, progress=False
    ).fit(frames)
    assert m.n_patterns_ >= 2
    p = so.default_params(frames, ws, 1.0, SIGNALS[signal])
    check_conditionals(m, frames, p, [0, 1, 7, 19, 39])


def test_training_log_likelihoods_match_the_formula():
    """Each training frame's log p(V_i | D_k) under every pattern, its own without it (the
    evidence phases can be fitted to): the numpy GP's predictive density, -inf for a frame alone
    in its pattern; the same with one or two threads."""
    frames = dpgp.datasets.synthetic("intersection", n_frames=40, seed=3)
    ws = (6.0, 8.0)
    kw = dict(iterations=3, length_scales=ws, noise_var=1.0, seed=1, progress=False)
    m = dpgp.DPGP(**kw).fit(frames)
    assert m.n_patterns_ >= 2
    p = so.default_params(frames, ws, 1.0)
    got = m.training_log_likelihoods()
    assert got.shape == (len(frames), m.n_patterns_)
    for i in range(len(frames)):
        for k in range(m.n_patterns_):
            others = np.flatnonzero((m.labels_ == k) & (np.arange(len(frames)) != i))
            if len(others) == 0:
                assert got[i, k] == -np.inf
                continue
            xy, v = so._rows(frames, others)
            want = so.gp_oracle.log_predictive(xy, v, frames[i].xy, frames[i].v, p)
            assert got[i, k] == pytest.approx(want, rel=1e-9, abs=1e-8), (i, k)
    two = dpgp.DPGP(n_threads=2, **kw).fit(frames)
    np.testing.assert_array_equal(two.training_log_likelihoods(), got)


# --- (c) recovery -------------------------------------------------------------------------------
@pytest.mark.parametrize("assignment", ["gibbs", "map"])
@pytest.mark.parametrize("kind", ["highway", "intersection"])
def test_recovers_the_true_patterns_of_synthetic_scenes(kind, assignment):
    frames = dpgp.datasets.synthetic(kind, n_frames=120, seed=11)
    m = dpgp.DPGP(iterations=20, assignment=assignment, seed=0, progress=False).fit(frames)
    ari = so.adjusted_rand_index(m.labels_, frames.labels)
    print(f"{kind}/{assignment}: ARI {ari:.3f}, K {m.n_patterns_}, weights {np.round(m.weights_, 3).tolist()}")
    assert ari >= 0.9, f"ARI {ari:.3f}; K = {m.n_patterns_}, weights {np.round(m.weights_, 3).tolist()}"
    assert np.all(np.diff(np.bincount(m.labels_)) <= 0)  # pattern 0 is the largest


# --- (d) determinism ----------------------------------------------------------------------------
@pytest.mark.parametrize("assignment", ["gibbs", "map"])
def test_same_seed_same_chain_with_one_or_two_threads(assignment):
    frames = dpgp.datasets.synthetic("intersection", n_frames=80, seed=5)
    fits = [
        dpgp.DPGP(iterations=8, assignment=assignment, seed=3, n_threads=t, progress=False, store_labels=True).fit(
            frames
        )
        for t in (1, 2)
    ]
    a, b = fits
    np.testing.assert_array_equal(a.labels_, b.labels_)
    np.testing.assert_array_equal(a.label_trace_, b.label_trace_)
    assert a.alpha_ == b.alpha_
    np.testing.assert_array_equal(a.length_scales_, b.length_scales_)
    assert a.history_["log_joint"] == b.history_["log_joint"]
    assert a.history_["alpha"] == b.history_["alpha"]


def test_different_seeds_give_different_chains():
    frames = dpgp.datasets.synthetic("highway", n_frames=60, seed=5)
    a, b = (dpgp.DPGP(iterations=6, seed=s, progress=False, store_labels=True).fit(frames) for s in (1, 2))
    assert a.history_["log_joint"] != b.history_["log_joint"]
    # with w and α fixed only the labels can differ: on the tiny problem they must
    _, p, alpha = so.tiny_problem(5)
    c, d = (fit_tiny(p, alpha, iterations=200, seed=s, store_labels=True) for s in (1, 2))
    assert not np.array_equal(c.label_trace_, d.label_trace_)


# --- (e) every likelihood and proposal targets its own posterior ---------------------------------
@pytest.mark.parametrize("likelihood,proposal", [("exact", "full"), ("hsgp", "full"), ("hsgp", "informed")])
def test_every_engine_matches_its_enumerated_posterior(likelihood, proposal):
    """exact/informed is the default and tested above. hsgp with 6 basis functions: patterns of
    more than 6 points compute through the M x M statistics, smaller ones densely, and the
    oracle enumerates the posterior of the reduced-rank kernel k̃ (hsgp_oracle)."""
    import dataclasses

    frames, p, alpha = so.tiny_problem(5)
    m = fit_tiny(
        p,
        alpha,
        iterations=SWEEPS,
        seed=7,
        store_labels=True,
        likelihood=likelihood,
        proposal=proposal,
        n_basis=(2, 3),
        sampler="collapsed",  # the collapsed sampler's proposals; tests/model/test_subcluster.py: the other
    )
    assert m.likelihood_ == likelihood
    target = p if likelihood == "exact" else dataclasses.replace(p, basis=m.basis_)
    parts, logp = so.partition_posterior(frames, target, alpha)
    got = so.empirical_partition_probs(m.label_trace_[BURN_IN:], parts)
    tv = so.total_variation(got, np.exp(logp))
    print(f"{likelihood}/{proposal}: TV {tv:.4f}")
    assert tv <= 0.03
    if likelihood == "hsgp":  # and the reduced-rank posterior is not the exact one here
        _, exact = so.partition_posterior(frames, p, alpha)
        assert so.total_variation(np.exp(exact), np.exp(logp)) > 0.03
