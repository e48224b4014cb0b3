"""A plain numpy implementation of the reduced-rank (HSGP) kernel, written from the formulas
(Solin & Särkkä 2020) independently of the Rust core: the oracle dpgp.hsgp is tested against.

The core computes through the M x M weight-space statistics; this oracle builds the n x n kernel
matrix ``k̃(X, X) = Φ diag(s) Φᵀ`` and uses the dense formulas of gp_oracle.
"""

from __future__ import annotations

import numpy as np


def eigenfunctions(u: np.ndarray, center: float, half: float, m: int) -> np.ndarray:
    """``(len(u), m)``: φ_j(u) = sin(π j (u − c + L) / (2L)) / √L, zero outside [c − L, c + L]."""
    j = np.arange(1, m + 1)
    t = u - center + half
    phi = np.sin(np.pi * np.outer(t, j) / (2 * half)) / np.sqrt(half)
    phi[(t < 0) | (t > 2 * half)] = 0.0
    return phi


def features(xy: np.ndarray, basis) -> np.ndarray:
    """``(n, M)`` with column ``j + m_x k`` = φ_j(x) φ_k(y)."""
    (cx, cy), (hx, hy), (mx, my) = basis.center, basis.half_widths, basis.counts
    fx = eigenfunctions(xy[:, 0], cx, hx, mx)
    fy = eigenfunctions(xy[:, 1], cy, hy, my)
    return (fy[:, :, None] * fx[:, None, :]).reshape(len(xy), mx * my)


def spectral(basis, length_scales) -> np.ndarray:
    """``(M,)`` unit spectral densities of the SE kernel at the basis frequencies."""
    (hx, hy), (mx, my) = basis.half_widths, basis.counts
    wx, wy = length_scales

    def s(w, half, m):
        omega = np.pi * np.arange(1, m + 1) / (2 * half)
        return np.sqrt(2 * np.pi) * w * np.exp(-0.5 * (w * omega) ** 2)

    return np.outer(s(wy, hy, my), s(wx, hx, mx)).ravel()


def corr(a: np.ndarray, b: np.ndarray, length_scales, basis) -> np.ndarray:
    """k̃(a, b) / σ²."""
    return features(a, basis) @ np.diag(spectral(basis, length_scales)) @ features(b, basis).T


def inside(xy: np.ndarray, basis) -> np.ndarray:
    c, h = np.asarray(basis.center), np.asarray(basis.half_widths)
    return np.all(np.abs(xy - c) <= h, axis=1)
