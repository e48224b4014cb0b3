"""A plain numpy/scipy implementation of the DP-GP sampler's target, written from the formulas
(docs/model.md) independently of the Rust core: the oracle the sampler is tested against.

With the length scales w fixed for every pattern and the concentration α fixed, the posterior
over partitions z of the N frames is

    p(z | V) ∝ α^K · Π_k Γ(n_k) · Π_k p(D_k | w),

n_k the number of frames in pattern k and p(D_k | w) the GP marginal likelihood of all rows of
its frames. The collapsed conditional of frame i given the others' labels is, up to a constant,
log n_k^{-i} + log p(V_i | D_k \\ i) for an existing pattern and log α + log p(V_i | w) for a new
one (Neal's Algorithm 8 with w fixed: every auxiliary pattern has the same prior likelihood).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from math import lgamma

import numpy as np
from scipy.special import logsumexp

import gp_oracle


@dataclass(frozen=True)
class Params:
    """What gp_oracle reads: ``length_scales``, ``signal_var``, ``noise_var``, ``mean``."""

    length_scales: tuple[float, float]
    signal_var: tuple[float, float]
    noise_var: tuple[float, float] = (1.0, 1.0)  # one number: both outputs
    mean: tuple[float, float] = (0.0, 0.0)
    #: A dpgp.hsgp.Basis for the reduced-rank kernel; None for the squared exponential.
    basis: object = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "noise_var", tuple(map(float, np.broadcast_to(self.noise_var, 2))))


def default_params(frames, length_scales, noise_var=1.0, signal_var=None, mean=None) -> Params:
    """The estimator's defaults: variance (ddof=0) and mean of each output over all rows."""
    sv = np.var(frames.v, axis=0) if signal_var is None else np.broadcast_to(signal_var, 2)
    mu = frames.v.mean(axis=0) if mean is None else np.broadcast_to(mean, 2)
    return Params(tuple(map(float, length_scales)), tuple(map(float, sv)), noise_var, tuple(map(float, mu)))


# --- partitions and labels --------------------------------------------------------------------
def set_partitions(n: int) -> np.ndarray:
    """Every partition of n items as a canonical label vector (restricted growth string),
    shape (Bell(n), n), in lexicographic order."""
    out: list[list[int]] = []

    def grow(prefix: list[int], k: int) -> None:
        if len(prefix) == n:
            out.append(prefix.copy())
            return
        for c in range(k + 1):
            prefix.append(c)
            grow(prefix, max(k, c + 1))
            prefix.pop()

    grow([], 0)
    return np.array(out, dtype=np.int64).reshape(len(out), n)


def canonical(labels) -> np.ndarray:
    """Relabel in order of first appearance: the first item gets 0, the next new label 1, ..."""
    labels = np.asarray(labels)
    _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first)] = np.arange(len(first))
    return rank[inverse.reshape(labels.shape)]


def adjusted_rand_index(a, b) -> float:
    """Hubert & Arabie's adjusted Rand index of two labelings of the same items."""
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"labelings must be 1-d of equal length, got {a.shape} and {b.shape}")
    _, ai = np.unique(a, return_inverse=True)
    _, bi = np.unique(b, return_inverse=True)
    table = np.zeros((ai.max() + 1, bi.max() + 1), dtype=np.int64)
    np.add.at(table, (ai, bi), 1)

    def pairs(x):
        return float(np.sum(x * (x - 1)) / 2)

    index, sa, sb = pairs(table), pairs(table.sum(axis=1)), pairs(table.sum(axis=0))
    total = len(a) * (len(a) - 1) / 2
    expected = sa * sb / total if total else 0.0
    top = (sa + sb) / 2
    if top == expected:  # both labelings trivial in the same way (one group, or all singletons)
        return 1.0
    return (index - expected) / (top - expected)


# --- the target ---------------------------------------------------------------------------------
def _rows(frames, members) -> tuple[np.ndarray, np.ndarray]:
    idx = np.concatenate([np.arange(frames.offsets[j], frames.offsets[j + 1]) for j in members])
    return frames.xy[idx], frames.v[idx]


def log_partition_weight(frames, labels, p: Params, alpha: float) -> float:
    """log [α^K Π_k Γ(n_k) p(D_k | w)]: the unnormalised log posterior of a partition."""
    labels = np.asarray(labels)
    total = 0.0
    for k in np.unique(labels):
        members = np.flatnonzero(labels == k)
        xy, v = _rows(frames, members)
        total += np.log(alpha) + lgamma(len(members)) + gp_oracle.log_marginal_likelihood(xy, v, p)
    return total


def partition_posterior(frames, p: Params, alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """``(partitions (B, N), log_probs (B,))``: the exact posterior over every partition."""
    parts = set_partitions(len(frames))
    logw = np.array([log_partition_weight(frames, z, p, alpha) for z in parts])
    return parts, logw - logsumexp(logw)


def unnormalised_conditional(frames, labels, i: int, p: Params, alpha: float) -> np.ndarray:
    """``(K+1,)``: log n_k^{-i} + log p(V_i | D_k \\ i) for k = 0..K-1 (``labels`` take the values
    0..K-1), then log α + log p(V_i | w) for a new pattern. -inf where n_k^{-i} = 0."""
    labels = np.asarray(labels)
    K = int(labels.max()) + 1
    fi = frames[i]
    out = np.empty(K + 1)
    for k in range(K):
        others = np.flatnonzero((labels == k) & (np.arange(len(labels)) != i))
        if len(others) == 0:
            out[k] = -np.inf
            continue
        xy, v = _rows(frames, others)
        out[k] = np.log(len(others)) + gp_oracle.log_predictive(xy, v, fi.xy, fi.v, p)
    out[K] = np.log(alpha) + gp_oracle.log_marginal_likelihood(fi.xy, fi.v, p)
    return out


def conditional_log_probs(frames, labels, i: int, p: Params, alpha: float) -> np.ndarray:
    """The normalised collapsed conditional of frame i (the layout of ``DPGP.conditional_log_probs``)."""
    u = unnormalised_conditional(frames, labels, i, p, alpha)
    return u - logsumexp(u)


def total_variation(p, q) -> float:
    return 0.5 * float(np.sum(np.abs(np.asarray(p) - np.asarray(q))))


def empirical_partition_probs(trace, parts: np.ndarray) -> np.ndarray:
    """Frequencies of each partition of ``parts`` (canonical rows) among the rows of ``trace``."""
    trace = np.asarray([canonical(row) for row in np.asarray(trace)])
    index = {tuple(z): j for j, z in enumerate(parts)}
    counts = np.zeros(len(parts))
    for row in trace:
        counts[index[tuple(row)]] += 1
    return counts / len(trace)


# --- a tiny problem whose posterior is spread over many partitions ----------------------------
def tiny_problem(n: int = 5, seed: int = 3):
    """``(frames, params, alpha)``: n frames of 2-3 vehicles in a 6 m square, from two loosely
    different fields, so the posterior spreads over many partitions (for n = 5: largest
    probability 0.11, 35 of the 52 partitions above 1%, 0.49 from the CRP prior in total
    variation)."""
    import dpgp

    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        l = (2, 3)[i % 2]
        shift = 1.5 * (i % 2)
        x, y = rng.uniform(0, 6, l), rng.uniform(0, 6, l)
        vx, vy = 1.0 + shift + rng.normal(0, 1, l), -0.5 + 0.5 * shift + rng.normal(0, 1, l)
        rows.append(np.column_stack([np.full(l, i), x, y, vx, vy]))
    a = np.vstack(rows)
    frames = dpgp.Frames.from_arrays(a[:, 0].astype(int), a[:, 1], a[:, 2], a[:, 3], a[:, 4])
    return frames, Params((3.0, 4.0), (1.0, 2.0), 1.0, (1.0, 0.0)), 1.0


def reference_gibbs(frames, p: Params, alpha: float, sweeps: int, seed: int = 0) -> np.ndarray:
    """A collapsed Gibbs chain for a few frames (n ≤ ~10) with w and α fixed, from the ratio of
    marginal likelihoods of every subset (computed once): ``(sweeps, n)`` canonical labels.
    Used to check the oracle and to calibrate how close a correct chain gets in a given length."""
    import math
    import random

    n = len(frames)
    lml = [0.0] * (1 << n)
    for m in range(1, 1 << n):
        xy, v = _rows(frames, [j for j in range(n) if m >> j & 1])
        lml[m] = gp_oracle.log_marginal_likelihood(xy, v, p)
    rnd = random.Random(seed)
    z = [0] * n
    trace = np.empty((sweeps, n), dtype=np.int64)
    for s in range(sweeps):
        for i in range(n):
            masks: dict[int, int] = {}
            for j in range(n):
                if j != i:
                    masks[z[j]] = masks.get(z[j], 0) | (1 << j)
            keys = list(masks)
            u = [math.log(bin(masks[k]).count("1")) + lml[masks[k] | 1 << i] - lml[masks[k]] for k in keys]
            u.append(math.log(alpha) + lml[1 << i])
            top = max(u)
            w = [math.exp(x - top) for x in u]
            c = rnd.choices(range(len(u)), weights=w)[0]
            z[i] = keys[c] if c < len(keys) else max(z) + 1
            seen: dict[int, int] = {}
            z = [seen.setdefault(x, len(seen)) for x in z]
        trace[s] = z
    return trace


# --- the noise summed out on a grid -------------------------------------------------------------
def log_noise_prior(log_noise: np.ndarray, signal_var: float, prior: tuple[float, float]) -> np.ndarray:
    """Log density of log σ_n² under log(σ_n² / σ²) ~ N(prior[0], prior[1]²)."""
    m, sd = prior
    z = (np.asarray(log_noise) - np.log(signal_var) - m) / sd
    return -0.5 * z**2 - np.log(sd) - 0.5 * np.log(2 * np.pi)


def _noise_grid(p, prior, grid: int, span: float) -> tuple[list[np.ndarray], tuple[float, float]]:
    """Per component, ``grid`` values of log σ_n² over the prior's mean ± ``span`` sds, and the
    reference pair (the grids' middle points) the lines of the noise-summed posteriors cross."""
    axes = []
    for d in range(2):
        centre = np.log(p.signal_var[d]) + prior[0]
        axes.append(np.linspace(centre - span * prior[1], centre + span * prior[1], grid))
    return axes, (float(np.exp(axes[0][grid // 2])), float(np.exp(axes[1][grid // 2])))


def partition_posterior_noise_summed(
    frames, p: Params, alpha: float, prior: tuple[float, float], grid: int = 81, span: float = 5.0
):
    """``(partitions, log_probs)``: the posterior over partitions with the noise pair summed out,

        p(z | V) ∝ α^K Π_k Γ(n_k) ∫∫ Π_k p(D_k | w, σ_x², σ_y²) p(σ_x²) p(σ_y²),

    on a grid of ``grid`` points per component over the prior's mean ± ``span`` sds of
    log σ_n² (trapezoid weights). The two outputs are independent GPs given the partition, so
    log p(D | σ_x², σ_y²) = l_x(σ_x²) + l_y(σ_y²): each subset's marginal is computed on two
    1-D lines through a reference point and added, l(a, b) = l(a, r) + l(r, b) − l(r, r)."""
    import dataclasses

    n = len(frames)
    parts = set_partitions(n)
    axes, ref = _noise_grid(p, prior, grid, span)
    # per subset (bitmask): l(a, r) over the x axis and l(r, b) over the y axis, and l(r, r)
    lines: dict[int, tuple[np.ndarray, np.ndarray, float]] = {}
    for mask in range(1, 1 << n):
        xy, v = _rows(frames, [j for j in range(n) if mask >> j & 1])
        lx = np.array(
            [
                gp_oracle.log_marginal_likelihood(xy, v, dataclasses.replace(p, noise_var=(float(np.exp(a)), ref[1])))
                for a in axes[0]
            ]
        )
        ly = np.array(
            [
                gp_oracle.log_marginal_likelihood(xy, v, dataclasses.replace(p, noise_var=(ref[0], float(np.exp(b)))))
                for b in axes[1]
            ]
        )
        lines[mask] = (lx, ly, gp_oracle.log_marginal_likelihood(xy, v, dataclasses.replace(p, noise_var=ref)))
    h = [ax[1] - ax[0] for ax in axes]
    trap = [np.log(np.r_[0.5, np.ones(grid - 2), 0.5] * hd) for hd in h]
    prior_x, prior_y = (log_noise_prior(axes[d], p.signal_var[d], prior) for d in range(2))
    logw = np.empty(len(parts))
    for t, z in enumerate(parts):
        sx, sy, rest = prior_x + trap[0], prior_y + trap[1], 0.0
        for k in np.unique(z):
            members = np.flatnonzero(z == k)
            lx, ly, lr = lines[int(sum(1 << int(j) for j in members))]
            sx, sy, rest = sx + lx, sy + ly, rest - lr + np.log(alpha) + lgamma(len(members))
        logw[t] = logsumexp(sx) + logsumexp(sy) + rest
    return parts, logw - logsumexp(logw)


def partition_posterior_noise_per_pattern(
    frames, p: Params, alpha: float, prior: tuple[float, float], grid: int = 81, span: float = 5.0
):
    """``(partitions, log_probs)``: the posterior over partitions when each pattern has its own
    noise pair under the prior, integrated out per pattern,

        p(z | V) ∝ α^K Π_k Γ(n_k) ∫∫ p(D_k | w, σ_x², σ_y²) p(σ_x²) p(σ_y²) dσ_x² dσ_y²,

    each output on a 1-D grid of ``grid`` points over the prior's mean ± ``span`` sds of log σ_n²
    (trapezoid weights), by the same split into two lines through a reference point as
    :func:`partition_posterior_noise_summed` (the outputs are independent GPs given the partition)."""
    import dataclasses

    n = len(frames)
    parts = set_partitions(n)
    axes, ref = _noise_grid(p, prior, grid, span)
    h = [ax[1] - ax[0] for ax in axes]
    trap = [np.log(np.r_[0.5, np.ones(grid - 2), 0.5] * hd) for hd in h]
    prior_x, prior_y = (log_noise_prior(axes[d], p.signal_var[d], prior) for d in range(2))
    # per subset (bitmask): log ∫∫ prior × p(D | σ²)
    own: dict[int, float] = {}
    for mask in range(1, 1 << n):
        xy, v = _rows(frames, [j for j in range(n) if mask >> j & 1])

        def lml(noise, xy=xy, v=v):
            return gp_oracle.log_marginal_likelihood(xy, v, dataclasses.replace(p, noise_var=noise))

        lx = np.array([lml((float(np.exp(a)), ref[1])) for a in axes[0]])
        ly = np.array([lml((ref[0], float(np.exp(b)))) for b in axes[1]])
        own[mask] = logsumexp(prior_x + trap[0] + lx) + logsumexp(prior_y + trap[1] + ly) - lml(ref)
    logw = np.empty(len(parts))
    for t, z in enumerate(parts):
        total = 0.0
        for k in np.unique(z):
            members = np.flatnonzero(z == k)
            total += own[int(sum(1 << int(j) for j in members))] + np.log(alpha) + lgamma(len(members))
        logw[t] = total
    return parts, logw - logsumexp(logw)


def partition_posterior_length_scales(
    frames, p: Params, alpha: float, prior: tuple[float, float], grid: int = 31, span: float = 3.0
):
    """``(partitions, log_probs)``: the posterior over partitions when each pattern has its own
    length scales under independent Gamma(shape, scale) ``prior``s, integrated out per pattern,

        p(z | V) ∝ α^K Π_k Γ(n_k) ∫∫ p(D_k | w_x, w_y) Γ(w_x) Γ(w_y) dw_x dw_y,

    on a ``grid x grid`` lattice of (log w_x, log w_y) over the prior's log-mean ± ``span`` sds of
    log w (trapezoid weights; the Jacobian w enters the density on the log scale)."""
    from scipy.stats import gamma

    n = len(frames)
    parts = set_partitions(n)
    a, b = prior
    sd = 1.0 / np.sqrt(a)  # of log w under Gamma(a, b), near enough for the lattice's extent
    axis = np.log(a * b) + np.linspace(-span * sd, span * sd, grid)
    h = axis[1] - axis[0]
    trap = np.log(np.r_[0.5, np.ones(grid - 2), 0.5] * h)
    log_prior = gamma.logpdf(np.exp(axis), a, scale=b) + axis + trap  # per axis, on the log scale
    own: dict[int, float] = {}
    for mask in range(1, 1 << n):
        xy, v = _rows(frames, [j for j in range(n) if mask >> j & 1])
        lml = np.array(
            [
                [
                    gp_oracle.log_marginal_likelihood(
                        xy, v, replace(p, length_scales=(float(np.exp(ux)), float(np.exp(uy))))
                    )
                    for uy in axis
                ]
                for ux in axis
            ]
        )
        own[mask] = logsumexp(lml + log_prior[:, None] + log_prior[None, :])
    logw = np.empty(len(parts))
    for t, z in enumerate(parts):
        logw[t] = sum(
            own[int(sum(1 << int(j) for j in np.flatnonzero(z == k)))] + np.log(alpha) + lgamma(int(np.sum(z == k)))
            for k in np.unique(z)
        )
    return parts, logw - logsumexp(logw)
