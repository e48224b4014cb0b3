"""Split–merge moves and the noise sampled inside the chain (docs/inference.md) against the
numpy oracle (sampler_oracle.py):

(a) with split–merge on, partition frequencies on 5 tiny frames match the enumerated posterior
    (total variation ≤ 0.03) for every likelihood × proposal;
(b) with the noise sampled too, they match the posterior with the noise summed out on a grid;
(c) history_ records the moves and the noise; bad settings are typed errors;
(d) the chain with both on is the same whatever the thread count, and the same in other units.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import dpgp
from dpgp.gp import defaults

import sampler_oracle as so

SWEEPS, BURN_IN = 30_000, 1_000
# hsgp runs the sub-cluster sampler here (sampler="auto"), which has no frame proposal: its
# "informed" variant was the "full" chain bit for bit, and is not run twice.
VARIANTS = [("exact", "full"), ("exact", "informed"), ("hsgp", "full")]


def fit_tiny(p, alpha, **kw):
    frames, _, _ = so.tiny_problem(5)
    settings = dict(
        assignment="gibbs", length_scales=p.length_scales, signal_var=p.signal_var, mean=p.mean,
        noise_var=p.noise_var, alpha=alpha, progress=False, iterations=SWEEPS, store_labels=True,
        n_basis=(2, 3),
    )  # fmt: skip
    return dpgp.DPGP(**{**settings, **kw}).fit(frames)


def target(p, m):
    return p if m.likelihood_ == "exact" else dataclasses.replace(p, basis=m.basis_)


@pytest.mark.parametrize("likelihood,proposal", VARIANTS)
def test_split_merge_chain_matches_the_enumerated_posterior(likelihood, proposal):
    frames, p, alpha = so.tiny_problem(5)
    m = fit_tiny(
        p, alpha, seed=11, likelihood=likelihood, proposal=proposal, split_merge=3, split_merge_pairs="informed"
    )
    parts, logp = so.partition_posterior(frames, target(p, m), alpha)
    got = so.empirical_partition_probs(m.label_trace_[BURN_IN:], parts)
    tv = so.total_variation(got, np.exp(logp))
    h = m.history_
    acc = sum(h["split_accepted"]) + sum(h["merge_accepted"])
    print(f"{likelihood}/{proposal} + split-merge: TV {tv:.4f}, {acc} accepted of {3 * SWEEPS}")
    assert tv <= 0.03
    assert sum(h["split_proposed"]) + sum(h["merge_proposed"]) == 3 * SWEEPS and acc > 1000


@pytest.mark.parametrize("likelihood,proposal", VARIANTS)
def test_sampled_noise_chain_matches_the_posterior_with_the_noise_summed_out(likelihood, proposal):
    frames, p, alpha = so.tiny_problem(5)
    m = fit_tiny(p, alpha, seed=12, likelihood=likelihood, proposal=proposal, noise_var="global", split_merge=2)
    assert m.defaults_.noise_var_source == "sampled"
    parts, logp = so.partition_posterior_noise_summed(frames, target(p, m), alpha, defaults.NOISE_PRIOR)
    got = so.empirical_partition_probs(m.label_trace_[BURN_IN:], parts)
    tv = so.total_variation(got, np.exp(logp))
    # the noise changes the answer here: the posterior with σ_n² fixed at 1 is another one
    _, fixed = so.partition_posterior(frames, target(p, m), alpha)
    print(
        f"{likelihood}/{proposal}, noise sampled: TV {tv:.4f} (to the fixed-noise posterior {so.total_variation(got, np.exp(fixed)):.4f})"
    )
    assert tv <= 0.03
    assert so.total_variation(np.exp(fixed), np.exp(logp)) > 0.03
    nx = np.asarray(m.history_["noise_var_x"])
    assert len(nx) == SWEEPS and len(np.unique(nx)) > SWEEPS // 2  # it moves


def test_history_records_moves_and_noise_and_bad_settings_are_errors():
    frames = dpgp.datasets.synthetic("intersection", n_frames=60, seed=2)
    m = dpgp.DPGP(iterations=4, seed=1, progress=False, split_merge=5, noise_var="global").fit(frames)
    h = m.history_
    for key in ("split_proposed", "split_accepted", "merge_proposed", "merge_accepted", "noise_var_x", "noise_var_y"):
        assert len(h[key]) == 4, key
    assert all(a + b == 5 for a, b in zip(h["split_proposed"], h["merge_proposed"]))
    assert all(a <= b for a, b in zip(h["split_accepted"], h["split_proposed"]))
    assert m.noise_var_ == (h["noise_var_x"][-1], h["noise_var_y"][-1]) == tuple(m.params_.noise_var)
    for bad in (dict(split_merge=-1), dict(split_merge="many"), dict(split_merge=1.5), dict(split_merge_pairs="near"),
                dict(noise_var="sampled")):  # fmt: skip
        with pytest.raises(dpgp.InvalidInputError):
            dpgp.DPGP(iterations=1, progress=False, **bad).fit(frames)


def test_pilots_stay_available():
    frames = dpgp.datasets.synthetic("intersection", n_frames=40, seed=5)
    m = dpgp.DPGP(iterations=1, seed=1, progress=False, noise_var="pilot").fit(frames)
    assert m.defaults_.noise_var_source == "pilot" and m.defaults_.noise_scores
    assert m.history_["noise_var_x"] == [m.noise_var_[0]]  # fixed at the pilots' value


def test_same_chain_with_one_or_two_threads():
    frames = dpgp.datasets.synthetic("intersection", n_frames=80, seed=5)
    a, b = (
        dpgp.DPGP(
            iterations=6,
            seed=3,
            n_threads=t,
            progress=False,
            store_labels=True,
            split_merge=10,
            split_merge_pairs="informed",
        ).fit(frames)  # fmt: skip
        for t in (1, 2)
    )
    np.testing.assert_array_equal(a.label_trace_, b.label_trace_)
    assert a.history_ == {**b.history_, "seconds": a.history_["seconds"]}


def test_same_chain_in_feet_and_metres():
    frames = dpgp.datasets.synthetic("intersection", n_frames=60, seed=4)
    c = 0.3048
    metres = dpgp.Frames(frames.ids, frames.offsets, frames.xy * c, frames.v * c, frames.labels)
    a = dpgp.DPGP(iterations=6, seed=2, progress=False, store_labels=True, split_merge=10).fit(frames)
    b = dpgp.DPGP(iterations=6, seed=2, progress=False, store_labels=True, split_merge=10).fit(metres)
    np.testing.assert_array_equal(a.label_trace_, b.label_trace_)
    np.testing.assert_allclose(
        np.asarray(b.history_["noise_var_x"]), np.asarray(a.history_["noise_var_x"]) * c**2, rtol=1e-6
    )
    np.testing.assert_allclose(
        np.asarray(b.history_["noise_var_y"]), np.asarray(a.history_["noise_var_y"]) * c**2, rtol=1e-6
    )
