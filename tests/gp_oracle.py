"""A plain numpy/scipy implementation of the GP formulas, written independently of the Rust core,
used as the oracle the core is tested against."""

from __future__ import annotations

import numpy as np
from scipy.linalg import cho_factor, cho_solve


def corr(a: np.ndarray, b: np.ndarray, wx: float, wy: float) -> np.ndarray:
    dx = a[:, None, 0] - b[None, :, 0]
    dy = a[:, None, 1] - b[None, :, 1]
    return np.exp(-(dx**2) / (2 * wx**2) - dy**2 / (2 * wy**2))


def kernel(p, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The correlation the parameters ``p`` ask for: the squared exponential, or the reduced-rank
    one when ``p`` carries a ``basis`` (hsgp_oracle)."""
    basis = getattr(p, "basis", None)
    if basis is None:
        return corr(a, b, *p.length_scales)
    import hsgp_oracle

    return hsgp_oracle.corr(a, b, p.length_scales, basis)


def mvn_logpdf(r: np.ndarray, cov: np.ndarray) -> float:
    c = cho_factor(cov, lower=True)
    logdet = 2 * np.sum(np.log(np.diag(c[0])))
    return float(-0.5 * r @ cho_solve(c, r) - 0.5 * logdet - 0.5 * len(r) * np.log(2 * np.pi))


def log_marginal_likelihood(xy, v, p) -> float:
    s2, sn2, mu = p.signal_var, p.noise_var, p.mean
    R = kernel(p, xy, xy)
    return sum(mvn_logpdf(v[:, d] - mu[d], s2[d] * R + sn2[d] * np.eye(len(xy))) for d in range(2))


def predictive_moments(train_xy, train_v, test_xy, p, d):
    """Mean and covariance of the noisy test velocities of output d given the training data."""
    s2, sn2, mu = p.signal_var[d], p.noise_var[d], p.mean[d]
    K = s2 * kernel(p, train_xy, train_xy) + sn2 * np.eye(len(train_xy))
    Ks = s2 * kernel(p, train_xy, test_xy)
    Kss = s2 * kernel(p, test_xy, test_xy) + sn2 * np.eye(len(test_xy))
    c = cho_factor(K, lower=True)
    mean = mu + Ks.T @ cho_solve(c, train_v[:, d] - mu)
    cov = Kss - Ks.T @ cho_solve(c, Ks)
    return mean, cov


def log_predictive(train_xy, train_v, test_xy, test_v, p) -> float:
    total = 0.0
    for d in range(2):
        mean, cov = predictive_moments(train_xy, train_v, test_xy, p, d)
        total += mvn_logpdf(test_v[:, d] - mean, cov)
    return total


def posterior(train_xy, train_v, query_xy, p):
    s2, sn2, mu = p.signal_var, p.noise_var, p.mean
    R = kernel(p, train_xy, train_xy)
    Rq = kernel(p, train_xy, query_xy)
    prior = np.diag(kernel(p, query_xy, query_xy))
    mean = np.empty((len(query_xy), 2))
    var = np.empty((len(query_xy), 2))
    for d in range(2):
        c = cho_factor(s2[d] * R + sn2[d] * np.eye(len(train_xy)), lower=True)
        Ks = s2[d] * Rq
        mean[:, d] = mu[d] + Ks.T @ cho_solve(c, train_v[:, d] - mu[d])
        var[:, d] = s2[d] * prior - np.einsum("ij,ij->j", Ks, cho_solve(c, Ks))
    return mean, var
