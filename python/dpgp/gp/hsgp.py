"""The Hilbert-space reduced-rank GP (``likelihood="hsgp"``) on its own.

On a box ``[c − L, c + L]`` per axis, the Laplacian's Dirichlet eigenfunctions
``φ_j(u) = sin(π j (u − c + L) / (2L)) / √L`` (``j = 1..m``) form a separable basis
``φ_jk(x, y) = φ_j(x) φ_k(y)``, and the squared-exponential kernel is approximated by
``k̃(p, q) = σ² Σ_jk S_x(√λ_j) S_y(√λ_k) φ_jk(p) φ_jk(q)`` with ``√λ_j = π j / (2L)`` and the
kernel's spectral density ``S(ω) = √(2π) w exp(−w² ω² / 2)`` per axis (Solin & Särkkä 2020;
Riutort-Mayol et al. 2023). ``k̃`` is a kernel in its own right: an hsgp fit is the DP mixture of
GPs with kernel ``k̃``, and these functions are its exact densities, computed (in Rust) through
the additive ``M x M`` statistics of a pattern (``M = m_x m_y``). Outside the box the basis
has no support: the field is its mean there.

**Sizing rule** (:func:`basis_for`), per axis, with ``S`` the half-range of the training
positions, ``w_lo`` the 5% quantile and ``w_mid`` the median of the length-scale prior (or the
fixed length scales): half-width ``L = max(1.2 S, S + 2 w_mid)`` (the boundary distorts ``k̃``
within about two length scales of it) and ``m = ceil(2 L / w_lo)``, so that the highest
frequency is ``π / w_lo``, where the spectral density of ``w_lo`` has fallen to ``e^{−π²/2}``
(0.7%) of its peak and that of typical length scales to far less. At most 4096 basis functions
(both counts shrink in proportion past that).

**Heading.** For a field over position and previous heading (``GPParams.heading_scale`` finite),
a basis with ``harmonics = J`` multiplies each position function by ``1, cos h, sin h, …,
cos Jh, sin Jh`` with prior weights ``q_0² = I_0(z) e^{-z}``, ``q_j² = 2 I_j(z) e^{-z}``,
``z = w_h⁻²``: the periodic kernel's Fourier series, truncated. The heading functions ``j ≥ 1``
multiply only the lowest ``m'_x m'_y`` position functions (``heading_counts``; all of them when
None): ``M = m_x m_y + 2J m'_x m'_y``, and the kernel is ``q_0² k_m(p, p') + Σ_{j≥1} q_j²
cos(j (h − h')) k_m'(p, p')``, a valid kernel whose heading-dependent part varies over longer
distances than the field (every factorisation is ``M x M``: the full product costs ``(2J + 1)³``
times a field over position).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import _core
from .._arrays import as_pairs
from ..exceptions import InvalidInputError
from .exact import GPParams, _pair, as_headings

#: Most basis functions (M x M matrices of 8-byte floats: 128 MiB each at the cap).
MAX_BASIS = 4096


@dataclass(frozen=True)
class Basis:
    """A basis box: its centre, half-widths ``L`` and eigenfunction counts per axis."""

    center: tuple[float, float]
    half_widths: tuple[float, float]
    counts: tuple[int, int]
    #: Heading harmonics ``J`` (0: a field over position only).
    harmonics: int = 0
    #: Position functions per axis of the heading blocks ``m'`` (None: ``counts``).
    heading_counts: tuple[int, int] | None = None

    @property
    def size(self) -> int:
        """``M = m_x m_y + 2J m'_x m'_y``."""
        hx, hy = self.heading_counts or self.counts
        return self.counts[0] * self.counts[1] + 2 * self.harmonics * hx * hy

    def as_tuple(self) -> tuple[tuple[float, float], tuple[float, float], tuple[int, int]]:
        return (tuple(self.center), tuple(self.half_widths), tuple(self.counts))  # type: ignore[return-value]

    def to_dict(self) -> dict:
        d = {"center": list(self.center), "half_widths": list(self.half_widths), "counts": list(self.counts)}
        if self.harmonics:
            d["harmonics"] = self.harmonics
            if self.heading_counts is not None:
                d["heading_counts"] = list(self.heading_counts)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> Basis:
        center = tuple(float(x) for x in d["center"])
        half = tuple(float(x) for x in d["half_widths"])
        if len(center) != 2 or len(half) != 2 or not (np.all(np.isfinite(center)) and all(h > 0 for h in half)):
            raise InvalidInputError(f"a basis needs a finite centre and two positive half-widths, got {d!r}")
        harmonics = d.get("harmonics", 0)
        if not isinstance(harmonics, (int, np.integer)) or isinstance(harmonics, bool) or harmonics < 0:
            raise InvalidInputError(f"a basis's heading harmonics must be a non-negative integer, got {harmonics!r}")
        counts = _basis_counts(tuple(d["counts"]))
        heading_counts = d.get("heading_counts")
        if heading_counts is not None:
            heading_counts = _basis_counts(tuple(heading_counts))
            if heading_counts[0] > counts[0] or heading_counts[1] > counts[1]:
                raise InvalidInputError(
                    f"a basis's heading counts {heading_counts} must not exceed its counts {counts}"
                )
        return cls(center, half, counts, int(harmonics), heading_counts)


def _basis_counts(n_basis: Any) -> tuple[int, int]:
    try:
        mx, my = n_basis
        ok = all(isinstance(m, (int, np.integer)) and not isinstance(m, bool) and m >= 1 for m in (mx, my))
    except (TypeError, ValueError):
        ok = False
    if not ok or int(mx) * int(my) > MAX_BASIS:
        raise InvalidInputError(
            f"n_basis must be None or two positive integers (m_x, m_y) with m_x * m_y <= {MAX_BASIS}, got {n_basis!r}"
        )
    return (int(mx), int(my))


def basis_for(
    xy: object,
    length_scale_prior: tuple[float, float] = (10.0, 1.0),
    length_scales: tuple[float, float] | None = None,
    n_basis: tuple[int, int] | None = None,
) -> Basis:
    """The basis the sizing rule (module docstring) gives for training positions ``xy``."""
    prior = _pair("length_scale_prior", length_scale_prior)
    fixed = None if length_scales is None else _pair("length_scales", length_scales)
    counts = None if n_basis is None else _basis_counts(n_basis)
    c, h, m = _core.hsgp_basis(as_pairs("xy", xy), prior, fixed, counts)
    return Basis(tuple(c), tuple(h), tuple(m))  # type: ignore[arg-type]


def log_marginal_likelihood(xy: object, v: object, params: GPParams, basis: Basis, h: object = None) -> float:
    """``log p(v | xy, h)`` under the reduced-rank GP, summed over both outputs."""
    xy = as_pairs("xy", xy)
    return _core.hsgp_log_marginal_likelihood(
        xy, as_pairs("v", v), params.as_tuple(), basis.as_tuple(),
        as_headings("h", h, len(xy)), params.heading_scale, basis.harmonics, basis.heading_counts,
    )  # fmt: skip


def log_predictive(
    train_xy: object,
    train_v: object,
    test_xy: object,
    test_v: object,
    params: GPParams,
    basis: Basis,
    train_h: object = None,
    test_h: object = None,
) -> float:
    """Joint log density of the test velocities given the training data, reduced-rank GP."""
    train_xy, test_xy = as_pairs("train_xy", train_xy), as_pairs("test_xy", test_xy)
    return _core.hsgp_log_predictive(
        train_xy, as_pairs("train_v", train_v), test_xy, as_pairs("test_v", test_v), params.as_tuple(),
        basis.as_tuple(), as_headings("train_h", train_h, len(train_xy)),
        as_headings("test_h", test_h, len(test_xy)), params.heading_scale, basis.harmonics,
        basis.heading_counts,
    )  # fmt: skip


def posterior(
    train_xy: object,
    train_v: object,
    query_xy: object,
    params: GPParams,
    basis: Basis,
    train_h: object = None,
    query_h: object = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Posterior mean and latent variance ``(m, 2)`` each at ``query_xy`` (outside the box: the
    mean and the prior variance ``signal_var``)."""
    train_xy, query_xy = as_pairs("train_xy", train_xy), as_pairs("query_xy", query_xy)
    return _core.hsgp_posterior(
        train_xy, as_pairs("train_v", train_v), query_xy, params.as_tuple(), basis.as_tuple(),
        as_headings("train_h", train_h, len(train_xy)), as_headings("query_h", query_h, len(query_xy)),
        params.heading_scale, basis.harmonics, basis.heading_counts,
    )  # fmt: skip


__all__ = ["Basis", "MAX_BASIS", "basis_for", "log_marginal_likelihood", "log_predictive", "posterior"]
