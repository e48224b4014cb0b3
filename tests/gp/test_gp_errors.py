"""Bad input to the GP layer raises typed errors that name the problem; nothing panics."""

from __future__ import annotations

import numpy as np
import pytest

import dpgp
from dpgp import GPParams

P = GPParams((5.0, 10.0), (1.0, 2.0), 1.0, (0.0, 0.0))
XY = np.random.default_rng(0).uniform(0, 10, (6, 2))
V = np.random.default_rng(1).normal(size=(6, 2))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(length_scales=(0.0, 1.0)), "length scale w_x"),
        (dict(length_scales=(1.0, -3.0)), "length scale w_y"),
        (dict(length_scales=(np.nan, 1.0)), "length scale"),
        (dict(length_scales=(1.0, 1.0), signal_var=(1.0, 0.0)), "signal_var"),
        (dict(length_scales=(1.0, 1.0), noise_var=-1.0), "noise_var"),
        (dict(length_scales=(1.0, 1.0), noise_var=0.0), "noise_var"),
        (dict(length_scales=(1.0, 1.0), mean=(np.inf, 0.0)), "mean"),
        (dict(length_scales=(1.0, 2.0, 3.0)), "length_scales"),
    ],
)
def test_bad_params(kwargs, match):
    with pytest.raises(ValueError, match=match) as e:
        GPParams(**kwargs)
    assert isinstance(e.value, dpgp.DpgpError)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("which", ["xy", "v"])
def test_non_finite_inputs(bad, which):
    xy, v = XY.copy(), V.copy()
    (xy if which == "xy" else v)[3, 1] = bad
    with pytest.raises(dpgp.InvalidInputError, match=f"{which} contains a non-finite value"):
        dpgp.gp.log_marginal_likelihood(xy, v, P)


def test_non_finite_test_points():
    q = XY.copy()
    q[0, 0] = np.nan
    with pytest.raises(ValueError, match="query_xy contains a non-finite"):
        dpgp.gp.posterior(XY, V, q, P)
    with pytest.raises(ValueError, match="test_v contains a non-finite"):
        dpgp.gp.log_predictive(XY, V, XY, np.where(np.isnan(q), np.nan, V), P)


def test_mismatched_shapes():
    with pytest.raises(dpgp.ShapeError, match="xy has 6 points but v has 5"):
        dpgp.gp.log_marginal_likelihood(XY, V[:5], P)
    with pytest.raises(dpgp.ShapeError, match=r"must have shape \(n, 2\)"):
        dpgp.gp.log_marginal_likelihood(XY[:, :1], V, P)
    with pytest.raises(dpgp.ShapeError, match=r"must have shape \(n, 2\)"):
        dpgp.gp.posterior(XY, V, np.zeros(4), P)
    with pytest.raises(ValueError, match="train_xy has 6 points but train_v has 4"):
        dpgp.gp.log_predictive(XY, V[:4], XY, V, P)


@pytest.mark.parametrize("fn", ["lml", "pred_train", "pred_test", "post"])
def test_empty_arrays(fn):
    e = np.zeros((0, 2))
    with pytest.raises(dpgp.ShapeError, match="is empty"):
        if fn == "lml":
            dpgp.gp.log_marginal_likelihood(e, e, P)
        elif fn == "pred_train":
            dpgp.gp.log_predictive(e, e, XY, V, P)
        elif fn == "pred_test":
            dpgp.gp.log_predictive(XY, V, e, e, P)
        else:
            dpgp.gp.posterior(XY, V, e, P)


def test_non_numeric_and_non_contiguous_inputs():
    with pytest.raises(dpgp.InvalidInputError, match="must be numeric"):
        dpgp.gp.log_marginal_likelihood([["a", "b"]], [[1.0, 2.0]], P)
    # Fortran-ordered and strided views are accepted (copied to C order in Python).
    wide = np.asfortranarray(np.column_stack([XY[:, 0], XY[:, 0], XY[:, 1], XY[:, 1]]))[:, ::2]
    assert dpgp.gp.log_marginal_likelihood(wide, V, P) == pytest.approx(dpgp.gp.log_marginal_likelihood(XY, V, P))


def test_raw_core_rejects_bad_arrays_without_panicking():
    from dpgp import _core

    with pytest.raises(dpgp.ShapeError, match="C-contiguous"):
        _core.log_marginal_likelihood(np.asfortranarray(np.ones((3, 2)))[::2], np.ones((2, 2)), P.as_tuple())
    with pytest.raises(TypeError):
        _core.log_marginal_likelihood(np.ones((3, 2), dtype=np.int64), np.ones((3, 2)), P.as_tuple())
