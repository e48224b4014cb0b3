"""dpgp.diagnostics against ArviZ (the oracle): rank-normalised split-R̂ and bulk/tail ESS on
fixed synthetic draws, to 1e-6."""

import warnings

import numpy as np
import pytest

from dpgp import InvalidInputError, ShapeError, diagnostics

with warnings.catch_warnings():
    warnings.simplefilter("ignore")  # ArviZ's import-time FutureWarning about its refactor
    az = pytest.importorskip("arviz")


def _draws():
    """Fixed draws of every kind the sampler produces: iid, slowly mixing, a drifting chain,
    a discrete count with ties (like K), chains stuck in different places, odd lengths."""
    rng = np.random.default_rng(20210101)
    ar = np.zeros((4, 301))
    ar[:, 0] = rng.normal(size=4)
    for t in range(1, 301):
        ar[:, t] = 0.95 * ar[:, t - 1] + rng.normal(size=4)
    drift = rng.normal(size=(4, 200)) + np.linspace(0, 3, 200)
    stuck = rng.normal(size=(3, 150)) + np.array([[0.0], [0.0], [4.0]])
    return {
        "iid": rng.normal(size=(4, 500)),
        "ar(0.95)": ar,
        "drift": drift,
        "counts": rng.poisson(5, size=(4, 250)).astype(float),
        "stuck": stuck,
        "heavy tail": rng.standard_cauchy(size=(2, 97)),
        "two draws of K": rng.integers(11, 13, size=(4, 40)).astype(float),
        "one chain": rng.normal(size=(1, 64)),
        "short": rng.normal(size=(2, 5)),
    }


@pytest.mark.parametrize("name", list(_draws()))
def test_rhat_and_ess_match_arviz(name):
    x = _draws()[name]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref_rhat = float(az.rhat(x, method="rank")) if x.shape[0] > 1 else float("nan")
        ref_bulk = float(az.ess(x, method="bulk"))
        ref_tail = float(az.ess(x, method="tail"))
    np.testing.assert_allclose(diagnostics.rhat(x), ref_rhat, rtol=1e-6, equal_nan=True)
    np.testing.assert_allclose(diagnostics.ess_bulk(x), ref_bulk, rtol=1e-6)
    np.testing.assert_allclose(diagnostics.ess_tail(x), ref_tail, rtol=1e-6)
    assert diagnostics.ess(x, "bulk") == diagnostics.ess_bulk(x)


def test_diagnostics_tell_mixed_from_stuck_chains():
    d = _draws()
    assert diagnostics.rhat(d["iid"]) < 1.01
    assert diagnostics.rhat(d["stuck"]) > 1.5
    assert diagnostics.rhat(d["drift"]) > 1.1  # split halves catch a drift every chain shares
    assert diagnostics.ess_bulk(d["iid"]) > 1500
    assert diagnostics.ess_bulk(d["ar(0.95)"]) < 100


def test_constant_draws_follow_arviz_conventions():
    x = np.full((4, 50), 7.0)
    assert np.isnan(diagnostics.rhat(x))
    assert diagnostics.ess_bulk(x) == diagnostics.ess_tail(x) == 200.0
    assert np.isnan(diagnostics.rhat(np.zeros((4, 3))))  # too few draws


def test_bad_draws_raise_typed_errors():
    with pytest.raises(ShapeError, match="chains, draws"):
        diagnostics.rhat(np.zeros((2, 3, 4)))
    with pytest.raises(InvalidInputError, match="NaN"):
        diagnostics.ess_bulk(np.array([[1.0, np.nan, 2.0, 3.0, 4.0]]))
    with pytest.raises(InvalidInputError, match="bulk"):
        diagnostics.ess(np.zeros((2, 10)), "mean")
    with pytest.raises(InvalidInputError, match="prob"):
        diagnostics.ess_tail(np.random.default_rng(0).normal(size=(2, 10)), prob=0.7)
