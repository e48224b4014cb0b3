"""dynamics="sticky" (docs/dynamics.md) against a plain numpy oracle written from the prior:

    p(z, s | V) ∝ ρ^{#on} (1 − ρ)^{#off} · α^K Γ(α)/Γ(α + M) Π_k Γ(m_k) · Π_k p(D_k | w),

links s_t (frame t stays in its predecessor's pattern), m_k the fresh draws (run starts and
frames whose link is off) of pattern k, ρ ~ Beta(1, 1) integrated out:
B(1 + #on, 1 + #off) / B(1, 1). Label-sequence frequencies of the sampler (Gibbs + split–merge,
ρ sampled, w and α fixed) on 5 tiny frames in one run and in two: total variation ≤ 0.03; the
same chain is far from the posterior with the links' factor dropped. Then the estimator's API:
stickiness_, history_, the model file, unordered frames, bad settings, thread counts."""

from __future__ import annotations

import itertools
from math import lgamma

import numpy as np
import pytest
from scipy.special import betaln, logsumexp

import dpgp
from dpgp.exceptions import InvalidInputError, UnorderedFramesError

import gp_oracle
import sampler_oracle as so

SWEEPS, BURN_IN = 30_000, 1_000


def tiny(times):
    """The oracle's 5 tiny frames, with times as ids (a gap of more than one step ends a run)."""
    frames, p, alpha = so.tiny_problem(5)
    ids = np.repeat(np.asarray(times, dtype=float), np.diff(frames.offsets))
    framed = dpgp.Frames.from_arrays(ids, frames.xy[:, 0], frames.xy[:, 1], frames.v[:, 0], frames.v[:, 1])
    return framed, p, alpha


def predecessors(frames) -> np.ndarray:
    from dpgp.data.timeorder import time_order

    return time_order(frames).prev


def log_weight(frames, z, s, prev, p, alpha, drop_links=False) -> float | None:
    """log p(z, s, V) up to a constant (ρ integrated), None if a link joins two patterns."""
    on = off = 0
    m: dict[int, int] = {}
    for t, k in enumerate(z):
        if prev[t] >= 0 and s[t]:
            if z[prev[t]] != k:
                return None
            on += 1
            continue
        off += prev[t] >= 0
        m[k] = m.get(k, 0) + 1
    total = sum(m.values())
    w = len(m) * np.log(alpha) + lgamma(alpha) - lgamma(alpha + total) + sum(lgamma(c) for c in m.values())
    if not drop_links:
        w += betaln(1 + on, 1 + off) - betaln(1, 1)
    for k in set(z):
        xy, v = so._rows(frames, [j for j in range(len(z)) if z[j] == k])
        w += gp_oracle.log_marginal_likelihood(xy, v, p)
    return w


def posterior(frames, p, alpha, drop_links=False):
    prev = predecessors(frames)
    parts = so.set_partitions(len(frames))
    with_prev = [t for t in range(len(frames)) if prev[t] >= 0]
    logp = []
    for z in parts:
        ws = []
        for bits in itertools.product([False, True], repeat=len(with_prev)):
            s = np.zeros(len(frames), dtype=bool)
            s[with_prev] = bits
            w = log_weight(frames, list(z), s, prev, p, alpha, drop_links)
            if w is not None:
                ws.append(w)
        logp.append(logsumexp(ws))
    logp = np.array(logp)
    return parts, logp - logsumexp(logp)


def fit(frames, p, alpha, **kw):
    settings = dict(
        assignment="gibbs", length_scales=p.length_scales, signal_var=p.signal_var, mean=p.mean,
        noise_var=p.noise_var, alpha=alpha, progress=False, iterations=SWEEPS, store_labels=True,
        likelihood="exact", dynamics="sticky", split_merge=2,
    )  # fmt: skip
    return dpgp.DPGP(**{**settings, **kw}).fit(frames)


ONE_RUN = [0.0, 1.0, 2.0, 3.0, 4.0]
TWO_RUNS = [0.0, 1.0, 2.0, 4.0, 5.0]  # a gap after the third frame: runs 0 → 1 → 2 and 3 → 4


@pytest.mark.parametrize("times,proposal", [(ONE_RUN, "full"), (ONE_RUN, "informed"), (TWO_RUNS, "informed")])
def test_sticky_chain_matches_the_enumerated_posterior(times, proposal):
    frames, p, alpha = tiny(times)
    m = fit(frames, p, alpha, seed=5, proposal=proposal)
    parts, logp = posterior(frames, p, alpha)
    got = so.empirical_partition_probs(m.label_trace_[BURN_IN:], parts)
    tv = so.total_variation(got, np.exp(logp))
    print(f"{proposal} {times}: TV {tv:.4f}, rho {np.mean(m.history_['stickiness']):.3f}")
    assert tv <= 0.03
    if times is ONE_RUN and proposal == "full":
        _, wrong = posterior(frames, p, alpha, drop_links=True)
        bad = so.total_variation(got, np.exp(wrong))
        print(f"links' factor dropped: TV {bad:.4f}")
        assert bad > 0.06
        _, plain = so.partition_posterior(frames, p, alpha)
        assert so.total_variation(got, np.exp(plain)) > 0.06


def test_stickiness_history_and_model_file(tmp_path):
    frames, p, alpha = tiny(ONE_RUN)
    m = fit(frames, p, None, iterations=20, seed=1, store_labels=False, length_scales=None)
    assert 0 < m.stickiness_ < 1
    assert len(m.history_["stickiness"]) == 20 and m.history_["stickiness"][-1] == m.stickiness_
    m.save(tmp_path / "m.npz")
    back = dpgp.DPGP.load(tmp_path / "m.npz")
    assert back.dynamics == "sticky" and back.stickiness_ == m.stickiness_
    np.testing.assert_array_equal(back._sampler.links(), m._sampler.links())
    assert back.log_joint_ == pytest.approx(m.log_joint_, abs=1e-9)
    plain = dpgp.DPGP(iterations=2, progress=False).fit(frames)
    assert plain.stickiness_ is None and "stickiness" not in plain.history_


def test_unordered_frames_and_bad_settings_are_typed_errors():
    frames, p, alpha = so.tiny_problem(5)
    f2 = dpgp.Frames.from_arrays(
        [f"f{i}" for i in np.repeat(np.arange(5), np.diff(frames.offsets))], frames.xy[:, 0], frames.xy[:, 1],
        frames.v[:, 0], frames.v[:, 1],
    )  # fmt: skip
    with pytest.raises(UnorderedFramesError, match="dynamics='sticky' needs frames in time order"):
        dpgp.DPGP(iterations=1, progress=False, dynamics="sticky").fit(f2)
    ordered, _, _ = tiny(ONE_RUN)
    for bad in [dict(dynamics="markov"), dict(dynamics="sticky", checkpoint="x.npz")]:
        with pytest.raises(InvalidInputError):
            dpgp.DPGP(iterations=1, progress=False, **bad).fit(ordered)


def test_same_labels_with_one_or_two_threads():
    frames, p, alpha = tiny(TWO_RUNS)
    runs = [
        dpgp.DPGP(iterations=15, seed=3, progress=False, dynamics="sticky", store_labels=True, n_threads=n).fit(frames)
        for n in (1, 2)
    ]
    np.testing.assert_array_equal(runs[0].label_trace_, runs[1].label_trace_)
    assert runs[0].history_["stickiness"] == runs[1].history_["stickiness"]
