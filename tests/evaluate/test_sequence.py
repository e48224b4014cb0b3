"""Held-out dynamics scores (issue 20): the HMM forward pass against a sum over every label path."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import dpgp
from dpgp.data.timeorder import time_order
from dpgp.evaluate.sequence import forward_log_likelihoods, sequence_scores


def _brute_force(log_e, a, start, seq):
    """log p(x_seq) by summing over every label path (no recursion shared with the forward pass)."""
    s = log_e.shape[1]
    total = 0.0
    for path in itertools.product(range(s), repeat=len(seq)):
        p = start[path[0]] * np.exp(log_e[seq[0], path[0]])
        for (_t0, z0), (t1, z1) in zip(zip(seq, path), zip(seq[1:], path[1:])):
            p *= a[z0, z1] * np.exp(log_e[t1, z1])
        total += p
    return np.log(total)


@pytest.mark.parametrize("seed", range(4))
def test_forward_pass_matches_the_sum_over_paths(seed):
    rng = np.random.default_rng(seed)
    times = np.array([0.0, 0.5, 1.0, 1.5, 3.0, 3.5])  # two runs: a gap after 1.5 s
    log_e = rng.normal(size=(6, 3))
    a = rng.dirichlet(np.ones(3), size=3)
    start = rng.dirichlet(np.ones(3))
    order = time_order(times)
    out = forward_log_likelihoods(log_e, np.log(a), np.log(start), order)
    for seq in order.sequences():
        # the chain rule: the conditionals of a run sum to the run's joint log-likelihood
        assert out[seq].sum() == pytest.approx(_brute_force(log_e, a, start, seq.tolist()), abs=1e-10)
        assert out[seq[0]] == pytest.approx(_brute_force(log_e, a, start, [int(seq[0])]), abs=1e-10)


def test_sequence_scores_of_a_fit_count_the_held_out_frames():
    f = dpgp.datasets.synthetic("intersection", n_frames=60, seed=4)
    m = dpgp.DPGP(iterations=3, seed=0, progress=False).fit(f[:40])
    s = sequence_scores(m, f[40:])
    assert s.n_frames == 20 and s.n_runs == 1 and s.n_vehicles == int(np.diff(f[40:].offsets).sum())
    assert np.isfinite([s.label_markov, s.label_independent, s.density_markov, s.density_independent]).all()
    assert np.isnan(s.label_phases)
    # under phases: the held-out labels' log-likelihood by the sum over every phase path
    ph = m.phases(2)
    z = np.argmax(
        m._fitted().log_scores(f[40:])[0] + np.log(np.r_[np.bincount(m.labels_, minlength=m.n_patterns_)]), axis=1
    )
    with_phases = sequence_scores(m, f[40:], phases=ph)
    log_e = np.log(ph.emission[:, z].T)
    want = _brute_force(log_e[:8], ph.trans, ph.start, list(range(8)))  # the first 8 frames: 2^8 paths
    short = sequence_scores(m, f[40:48], phases=ph)
    assert short.label_phases * 8 == pytest.approx(want, abs=1e-9)
    assert np.isfinite(with_phases.label_phases) and with_phases.label_markov == s.label_markov


def test_bad_smoothing_is_an_error():
    f = dpgp.datasets.synthetic("intersection", n_frames=12, seed=4)
    m = dpgp.DPGP(iterations=1, seed=0, progress=False).fit(f)
    with pytest.raises(ValueError, match="smoothing"):
        sequence_scores(m, f, smoothing=0)
