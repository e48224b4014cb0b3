"""Multi-chain convergence diagnostics: rank-normalised split-R̂ and bulk/tail effective sample
size, as defined by Vehtari, Gelman, Simpson, Carpenter & Bürkner (2021), "Rank-normalization,
folding, and localization: an improved R̂ for assessing convergence of MCMC", Bayesian Analysis.

Every function takes draws shaped ``(chains, draws)``. The estimators follow the paper (and
Stan): chains are split in halves, draws are replaced by the normal scores of their pooled
ranks, R̂ is the larger of the bulk value and the value for the draws folded about the median,
and the ESS uses Geyer's initial monotone sequence on the FFT autocovariance. They agree with
ArviZ's ``rhat(method="rank")`` and ``ess(method="bulk" | "tail")`` (checked in the tests);
only numpy and the standard library are needed here.
"""

from __future__ import annotations

from statistics import NormalDist

import numpy as np

from ..exceptions import InvalidInputError, ShapeError

_MIN_DRAWS = 4
_normal_quantile = np.vectorize(NormalDist().inv_cdf, otypes=[float])


def _draws(x: object, min_chains: int) -> np.ndarray | None:
    """Draws as a float (chains, draws) array, or None when too few to say anything."""
    a = np.asarray(x, dtype=float)
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2:
        raise ShapeError(f"draws must be shaped (chains, draws), got {a.shape}")
    if np.isnan(a).any():
        raise InvalidInputError("draws contain NaN")
    if a.shape[0] < min_chains or a.shape[1] < _MIN_DRAWS:
        return None
    return a


def split_chains(a: np.ndarray) -> np.ndarray:
    """Each chain cut into its first and last halves (the middle draw of an odd length dropped),
    so that a chain that drifts shows up as two disagreeing chains."""
    half = a.shape[1] // 2
    return np.concatenate([a[:, :half], a[:, a.shape[1] - half :]], axis=0)


def average_ranks(x: np.ndarray) -> np.ndarray:
    """Ranks 1..n of the pooled values, ties sharing their average rank (K is discrete)."""
    flat = x.ravel()
    _, inverse, counts = np.unique(flat, return_inverse=True, return_counts=True)
    upper = np.cumsum(counts)
    return (upper - (counts - 1) / 2.0)[inverse].reshape(x.shape)


def normal_scores(x: np.ndarray) -> np.ndarray:
    """Rank normalisation: Φ⁻¹((r - 3/8) / (n + 1/4)) of the pooled average ranks (Blom)."""
    r = average_ranks(x)
    return _normal_quantile((r - 0.375) / (x.size + 0.25))


def _basic_rhat(a: np.ndarray) -> float:
    """Gelman–Rubin R̂ of chains that are already split (NaN if every chain is constant)."""
    n = a.shape[1]
    within = a.var(axis=1, ddof=1).mean()
    between = n * a.mean(axis=1).var(ddof=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return float(np.sqrt((between / within + n - 1) / n))


def rhat(x: object) -> float:
    """Rank-normalised split-R̂: max of the bulk R̂ and the R̂ of the draws folded about their
    median. NaN with fewer than 2 chains or 4 draws, or when every draw is equal."""
    a = _draws(x, min_chains=2)
    if a is None:
        return float("nan")
    s = split_chains(a)
    bulk = _basic_rhat(normal_scores(s))
    tail = _basic_rhat(normal_scores(np.abs(s - np.median(s))))
    return float(max(bulk, tail))


def _autocovariance(a: np.ndarray) -> np.ndarray:
    """Biased autocovariance of each chain at every lag, by FFT (zero-padded past 2n)."""
    n = a.shape[1]
    size = 1 << int(np.ceil(np.log2(2 * n)))
    f = np.fft.rfft(a - a.mean(axis=1, keepdims=True), n=size, axis=1)
    return np.fft.irfft(f * np.conjugate(f), n=size, axis=1)[:, :n] / n


def _basic_ess(a: np.ndarray) -> float:
    """ESS of chains that are already split: n·m / τ, τ from the multi-chain autocorrelation
    truncated by Geyer's initial positive sequence and made monotone."""
    m, n = a.shape
    if np.ptp(a) < np.finfo(float).resolution:
        return float(a.size)  # constant draws: every draw is as good as independent
    acov = _autocovariance(a)
    mean_var = acov[:, 0].mean() * n / (n - 1.0)  # W, the mean within-chain variance
    var_plus = mean_var * (n - 1.0) / n + (a.mean(axis=1).var(ddof=1) if m > 1 else 0.0)
    rho = 1.0 - (mean_var - acov.mean(axis=0)) / var_plus
    rho[0] = 1.0
    # Sum autocorrelations in pairs (ρ_{2k} + ρ_{2k+1}) while the pair sums stay positive.
    kept = np.zeros(n)
    kept[:2] = rho[:2]
    t = 1
    even, odd = 1.0, rho[1]
    while t < n - 3 and even + odd > 0.0:
        even, odd = rho[t + 1], rho[t + 2]
        if even + odd >= 0.0:
            kept[t + 1], kept[t + 2] = even, odd
        t += 2
    last = t - 2
    if even > 0.0:
        kept[last + 1] = even  # the positive even term past the last full pair
    # Monotone: no pair sum may exceed the one before it.
    for t in range(1, last - 1, 2):
        if kept[t + 1] + kept[t + 2] > kept[t - 1] + kept[t]:
            kept[t + 1] = kept[t + 2] = (kept[t - 1] + kept[t]) / 2.0
    total = a.size
    tau = -1.0 + 2.0 * kept[: last + 1].sum() + kept[last + 1 : last + 2].sum()
    tau = max(tau, 1.0 / np.log10(total))  # caps the ESS of antithetic chains at n·log10(n)
    return float(total / tau)


def ess_bulk(x: object) -> float:
    """Bulk ESS: the ESS of the rank-normalised split chains (how well the chains pin down the
    centre of the distribution). NaN with fewer than 4 draws."""
    a = _draws(x, min_chains=1)
    if a is None:
        return float("nan")
    return _basic_ess(normal_scores(split_chains(a)))


def _quantile7(a: np.ndarray, p: float) -> float:
    """The p-quantile of the pooled draws by Hyndman & Fan's type 7 (R's default), written as
    position n·p + (1 - p) on the 1-based order statistics. The position is rounded the way
    ArviZ (scipy's mquantiles) rounds it, so that a draw that is exactly the quantile falls on
    the same side of the indicator I(draw <= q)."""
    x = np.sort(a, axis=None)
    position = x.size * p + (1.0 - p)
    k = int(np.clip(np.floor(position), 1, x.size - 1))
    gamma = float(np.clip(position - k, 0.0, 1.0))
    return float((1.0 - gamma) * x[k - 1] + gamma * x[k])


def ess_tail(x: object, prob: float = 0.05) -> float:
    """Tail ESS: the smaller ESS of the indicators I(draw ≤ q) for the ``prob`` and ``1 - prob``
    quantiles q of the pooled draws (how well the chains pin down the 90% interval)."""
    a = _draws(x, min_chains=1)
    if a is None:
        return float("nan")
    if not 0.0 < prob < 0.5:
        raise InvalidInputError(f"prob must lie in (0, 0.5), got {prob}")
    out = []
    for p in (prob, 1.0 - prob):
        q = _quantile7(a, p)
        out.append(_basic_ess(split_chains((a <= q).astype(float))))
    return float(min(out))


def ess(x: object, method: str = "bulk") -> float:
    """``method="bulk"`` or ``"tail"`` ESS of draws shaped (chains, draws)."""
    if method == "bulk":
        return ess_bulk(x)
    if method == "tail":
        return ess_tail(x)
    raise InvalidInputError(f"method must be 'bulk' or 'tail', got {method!r}")


__all__ = ["rhat", "ess", "ess_bulk", "ess_tail", "split_chains", "normal_scores", "average_ranks"]
