"""The field over position and previous heading (issue 34) against an independent numpy/scipy
oracle: the product of the squared exponential and the periodic kernel, assembled as a dense
matrix, for the exact GP; for the reduced-rank GP, the dense reduced-rank position kernel times
the truncated Fourier series of the periodic kernel (the core works in weight space instead)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import ive

import dpgp.gp.exact as exact
import dpgp.gp.hsgp as hsgp
from dpgp.exceptions import InvalidInputError, ShapeError

import gp_oracle
import hsgp_oracle

RNG = np.random.default_rng(34)


def periodic(ha: np.ndarray, hb: np.ndarray, wh: float, harmonics: int | None = None) -> np.ndarray:
    """k_h(a, b) = exp(-2 sin²((a - b)/2) / wh²); with ``harmonics``, its Fourier series cut
    there. An unknown heading (NaN) on either side: the average over heading, I_0(z) e^-z."""
    z = 1.0 / wh**2
    d = ha[:, None] - hb[None, :]
    if harmonics is None:
        k = np.exp(-2.0 * np.sin(d / 2) ** 2 / wh**2)
    else:
        j = np.arange(harmonics + 1)
        q = ive(j, z) * np.where(j == 0, 1.0, 2.0)
        k = np.cos(d[..., None] * j) @ q
    return np.where(np.isnan(d), ive(0, z), k)


def dense_logml(K: np.ndarray, v: np.ndarray, p: exact.GPParams) -> float:
    n = len(v)
    return sum(
        gp_oracle.mvn_logpdf(v[:, d] - p.mean[d], p.signal_var[d] * K + p.noise_var[d] * np.eye(n)) for d in range(2)
    )


def dense_predictive(Ktt, Kts, Kss, tv, sv, p) -> float:
    total = 0.0
    for d in range(2):
        s2, n2, mu = p.signal_var[d], p.noise_var[d], p.mean[d]
        A = s2 * Ktt + n2 * np.eye(len(tv))
        B = s2 * Kts
        mean = mu + B.T @ np.linalg.solve(A, tv[:, d] - mu)
        cov = s2 * Kss + n2 * np.eye(len(sv)) - B.T @ np.linalg.solve(A, B)
        total += gp_oracle.mvn_logpdf(sv[:, d] - mean, cov)
    return total


def scene(n: int, unknown: float = 0.2):
    """Two opposite lanes 3 m apart: the case a field over position alone averages."""
    xy = np.column_stack([RNG.uniform(0, 60, n), RNG.choice([0.0, 3.0], n) + RNG.normal(0, 0.3, n)])
    east = xy[:, 1] < 1.5
    h = np.where(east, 0.0, np.pi) + RNG.normal(0, 0.1, n)
    v = np.column_stack([np.where(east, 12.0, -12.0), np.zeros(n)]) + RNG.normal(0, 0.5, (n, 2))
    h[RNG.random(n) < unknown] = np.nan
    return xy, v, h


PARAMS = [
    exact.GPParams((8.0, 4.0), (40.0, 2.0), (0.3, 0.1), (1.0, 0.0), heading_scale=0.7),
    exact.GPParams((5.0, 5.0), 30.0, 0.5, 0.0, heading_scale=1.5),
]


@pytest.mark.parametrize("p", PARAMS)
def test_exact_densities_equal_the_dense_product_kernel(p: exact.GPParams) -> None:
    xy, v, h = scene(40)
    sxy, sv, sh = scene(9)
    K = gp_oracle.corr(xy, xy, *p.length_scales) * periodic(h, h, p.heading_scale)
    assert exact.log_marginal_likelihood(xy, v, p, h) == pytest.approx(dense_logml(K, v, p), rel=1e-10)
    Kts = gp_oracle.corr(xy, sxy, *p.length_scales) * periodic(h, sh, p.heading_scale)
    Kss = gp_oracle.corr(sxy, sxy, *p.length_scales) * periodic(sh, sh, p.heading_scale)
    want = dense_predictive(K, Kts, Kss, v, sv, p)
    assert exact.log_predictive(xy, v, sxy, sv, p, h, sh) == pytest.approx(want, rel=1e-9)
    mean, var = exact.posterior(xy, v, sxy, p, h, sh)
    for d in range(2):
        A = p.signal_var[d] * K + p.noise_var[d] * np.eye(len(xy))
        B = p.signal_var[d] * Kts
        np.testing.assert_allclose(
            mean[:, d], p.mean[d] + B.T @ np.linalg.solve(A, v[:, d] - p.mean[d]), rtol=1e-9, atol=1e-9
        )
        prior = p.signal_var[d] * np.diag(Kss)
        np.testing.assert_allclose(
            var[:, d], prior - np.einsum("ij,ij->j", B, np.linalg.solve(A, B)), rtol=1e-8, atol=1e-9
        )


def test_heading_separates_opposite_lanes_where_position_alone_averages() -> None:
    """What the heading is for: at a point between the lanes, the eastbound field is eastbound."""
    xy, v, h = scene(60, unknown=0.0)
    p = PARAMS[0]
    blind = exact.GPParams(p.length_scales, p.signal_var, p.noise_var, p.mean)
    q = np.array([[30.0, 1.5], [30.0, 1.5]])
    mean_h, _ = exact.posterior(xy, v, q, p, h, np.array([0.0, np.pi]))
    mean_b, _ = exact.posterior(xy, v, q, blind)
    assert mean_h[0, 0] > 9 and mean_h[1, 0] < -9
    assert abs(mean_b[0, 0]) < 6  # the two lanes' average
    # ... and the data say so: the heading field is far more likely.
    assert exact.log_marginal_likelihood(xy, v, p, h) > exact.log_marginal_likelihood(xy, v, blind) + 50


def test_infinite_heading_scale_is_the_position_field_bit_for_bit() -> None:
    xy, v, h = scene(30)
    sxy, sv, sh = scene(5)
    blind = exact.GPParams((6.0, 3.0), 20.0, 0.4)
    assert exact.log_marginal_likelihood(xy, v, blind, h) == exact.log_marginal_likelihood(xy, v, blind)
    assert exact.log_predictive(xy, v, sxy, sv, blind, h, sh) == exact.log_predictive(xy, v, sxy, sv, blind)
    basis = hsgp.basis_for(xy, n_basis=(8, 4))
    assert hsgp.log_marginal_likelihood(xy, v, blind, basis, h) == hsgp.log_marginal_likelihood(xy, v, blind, basis)


@pytest.mark.parametrize("p", PARAMS)
@pytest.mark.parametrize("harmonics", [1, 3])
def test_reduced_rank_densities_equal_the_dense_truncated_kernel(p: exact.GPParams, harmonics: int) -> None:
    xy, v, h = scene(35)
    sxy, sv, sh = scene(7)
    basis = hsgp.Basis(*hsgp.basis_for(np.vstack([xy, sxy]), n_basis=(10, 4)).as_tuple(), harmonics=harmonics)

    def k(a, ha, b, hb):
        return hsgp_oracle.corr(a, b, p.length_scales, basis) * periodic(ha, hb, p.heading_scale, harmonics)

    K = k(xy, h, xy, h)
    assert hsgp.log_marginal_likelihood(xy, v, p, basis, h) == pytest.approx(dense_logml(K, v, p), rel=1e-9)
    want = dense_predictive(K, k(xy, h, sxy, sh), k(sxy, sh, sxy, sh), v, sv, p)
    assert hsgp.log_predictive(xy, v, sxy, sv, p, basis, h, sh) == pytest.approx(want, rel=1e-8)
    mean, _ = hsgp.posterior(xy, v, sxy, p, basis, h, sh)
    for d in range(2):
        A = p.signal_var[d] * K + p.noise_var[d] * np.eye(len(xy))
        B = p.signal_var[d] * k(xy, h, sxy, sh)
        np.testing.assert_allclose(
            mean[:, d], p.mean[d] + B.T @ np.linalg.solve(A, v[:, d] - p.mean[d]), rtol=1e-7, atol=1e-7
        )


@pytest.mark.parametrize("heading_counts", [(3, 2), (1, 1)])
def test_coarse_heading_blocks_are_the_sum_of_two_dense_kernels(heading_counts: tuple[int, int]) -> None:
    """Heading blocks on the lowest ``m'`` position functions: the kernel is ``q_0² k_m`` plus the
    truncated series' harmonics times ``k_m'``, the reduced-rank position kernel on the lowest
    ``m'`` functions of the same box (two dense oracles added)."""
    xy, v, h = scene(35)
    sxy, sv, sh = scene(7)
    p, harmonics = PARAMS[0], 2
    box = hsgp.basis_for(np.vstack([xy, sxy]), n_basis=(10, 4))
    basis = hsgp.Basis(*box.as_tuple(), harmonics=harmonics, heading_counts=heading_counts)
    assert basis.size == 40 + 2 * harmonics * heading_counts[0] * heading_counts[1]
    coarse = hsgp.Basis(box.center, box.half_widths, heading_counts)
    q0 = ive(0, 1.0 / p.heading_scale**2)

    def k(a, ha, b, hb):
        full = hsgp_oracle.corr(a, b, p.length_scales, box)
        return q0 * full + (periodic(ha, hb, p.heading_scale, harmonics) - q0) * hsgp_oracle.corr(
            a, b, p.length_scales, coarse
        )

    K = k(xy, h, xy, h)
    assert hsgp.log_marginal_likelihood(xy, v, p, basis, h) == pytest.approx(dense_logml(K, v, p), rel=1e-9)
    want = dense_predictive(K, k(xy, h, sxy, sh), k(sxy, sh, sxy, sh), v, sv, p)
    assert hsgp.log_predictive(xy, v, sxy, sv, p, basis, h, sh) == pytest.approx(want, rel=1e-8)
    # Not the full product's density (the check has power).
    full = hsgp.Basis(*box.as_tuple(), harmonics=harmonics)
    assert abs(hsgp.log_marginal_likelihood(xy, v, p, full, h) - dense_logml(K, v, p)) > 1e-3
    assert hsgp.Basis.from_dict(basis.to_dict()) == basis
    with pytest.raises(InvalidInputError, match="heading counts"):
        hsgp.Basis.from_dict({**basis.to_dict(), "heading_counts": [11, 1]})


def test_reduced_rank_heading_field_approaches_the_exact_one() -> None:
    xy, v, h = scene(50)
    p = exact.GPParams((10.0, 6.0), 30.0, 0.5, heading_scale=1.0)
    basis = hsgp.Basis(*hsgp.basis_for(xy, n_basis=(24, 12)).as_tuple(), harmonics=6)
    got = hsgp.log_marginal_likelihood(xy, v, p, basis, h)
    assert got == pytest.approx(exact.log_marginal_likelihood(xy, v, p, h), abs=0.5)


def test_bad_headings_are_clear_errors() -> None:
    xy, v, h = scene(10)
    p = PARAMS[0]
    with pytest.raises(ShapeError, match="one heading per point"):
        exact.log_marginal_likelihood(xy, v, p, h[:5])
    with pytest.raises(InvalidInputError, match="infinite heading"):
        exact.log_marginal_likelihood(xy, v, p, np.where(np.arange(10) == 3, np.inf, h))
    for wh in (0.0, -1.0, np.nan):
        with pytest.raises(InvalidInputError, match="heading_scale"):
            exact.GPParams((5.0, 5.0), heading_scale=wh)
    with pytest.raises(InvalidInputError, match="heading harmonics"):
        hsgp.Basis.from_dict({"center": [0, 0], "half_widths": [1, 1], "counts": [2, 2], "harmonics": -1})
    big = hsgp.Basis((0.0, 0.0), (50.0, 50.0), (40, 40), harmonics=2)
    with pytest.raises(InvalidInputError, match="heading harmonics"):
        hsgp.log_marginal_likelihood(xy, v, p, big, h)
