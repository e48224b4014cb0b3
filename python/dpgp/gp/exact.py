"""The exact Gaussian-process layer on its own.

A motion pattern's velocity field has two independent outputs ``vx`` and ``vy``; output η is a GP
with constant mean ``mean[η]`` and covariance ``signal_var[η] * R + noise_var[η] * I``, where
``R`` is the anisotropic squared-exponential correlation with ``length_scales = (w_x, w_y)``.
These functions are what the sampler evaluates millions of times; they run in Rust.

A field over position and the vehicle's previous heading ``h`` (radians) multiplies ``R`` by the
periodic kernel ``exp(-2 sin²((h - h') / 2) / w_h²)``, ``w_h = GPParams.heading_scale``; pass each
point's heading (``NaN`` where a vehicle has no previous step: such a point observes the field
averaged over heading). ``heading_scale = inf``, the default, is the paper's field over position.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import _core
from .._arrays import MAX_MAGNITUDE, as_float_array, as_pairs
from ..exceptions import InvalidInputError, ShapeError


def _pair(name: str, value: object) -> tuple[float, float]:
    """A number (used for both outputs) or an ``(x, y)`` pair, as two floats."""
    arr = as_float_array(name, value)
    if arr.ndim == 0:
        return (float(arr), float(arr))
    if arr.shape == (2,):
        return (float(arr[0]), float(arr[1]))
    raise ShapeError(f"{name} must be a number or a pair (x, y), got {value!r}")


@dataclass(frozen=True)
class GPParams:
    """Hyperparameters of one pattern's GP.

    ``signal_var``, ``noise_var`` and ``mean`` take a pair ``(x, y)`` or one number used for
    both outputs (velocities along and across a road differ by orders of magnitude, so each
    output has its own noise variance).
    Length scales and variances must be positive (``InvalidInputError`` otherwise).
    """

    length_scales: tuple[float, float]
    signal_var: tuple[float, float] = (1.0, 1.0)
    noise_var: tuple[float, float] = (1.0, 1.0)
    mean: tuple[float, float] = (0.0, 0.0)
    #: ``w_h``, the length scale in the previous heading (radians); ``inf``: position only.
    heading_scale: float = float("inf")

    def __post_init__(self) -> None:
        wh = float(as_float_array("heading_scale", self.heading_scale))
        if not wh > 0:
            raise InvalidInputError(
                f"heading_scale must be positive (radians; inf for a field over position only), got {wh}"
            )
        object.__setattr__(self, "heading_scale", wh)
        object.__setattr__(self, "length_scales", _pair("length_scales", self.length_scales))
        object.__setattr__(self, "signal_var", _pair("signal_var", self.signal_var))
        object.__setattr__(self, "noise_var", _pair("noise_var", self.noise_var))
        object.__setattr__(self, "mean", _pair("mean", self.mean))
        _core.check_params(self.as_tuple())

    def as_tuple(self) -> tuple[float, float, float, float, float, float, float, float]:
        """``(w_x, w_y, σ_x², σ_y², σ_n,x², σ_n,y², μ_x, μ_y)``, the form the Rust core takes."""
        return (*self.length_scales, *self.signal_var, *self.noise_var, *self.mean)


def check_scales(v: np.ndarray, params: GPParams, what: str = "v") -> None:
    """Refuse velocities and parameters whose GP log density is not finite in double precision
    (:class:`~dpgp.InvalidInputError` naming the limit): ``|mean|``, ``σ²`` and ``σ_n²`` past
    1e100 (variances 1e200), or a velocity whose residual ``|v - mean|`` is more than 1e100
    noise standard deviations (its squared Mahalanobis term would overflow to -inf)."""
    mean, signal, noise = (np.asarray(getattr(params, k), dtype=float) for k in ("mean", "signal_var", "noise_var"))
    if np.max(np.abs(mean)) > MAX_MAGNITUDE or max(np.max(signal), np.max(noise)) > MAX_MAGNITUDE**2:
        raise InvalidInputError(
            f"mean {tuple(mean.tolist())}, signal_var {tuple(signal.tolist())} or noise_var {tuple(noise.tolist())} is beyond the limits "
            f"|mean| <= {MAX_MAGNITUDE:g}, variances <= {MAX_MAGNITUDE**2:g}; convert the velocities to sensible units"
        )
    v = np.asarray(v, dtype=float).reshape(-1, 2)
    finite = np.isfinite(v)  # NaN and inf: the core's own error names them
    if finite.any():
        with np.errstate(over="ignore", invalid="ignore"):
            worst = float(np.max((np.abs(v - mean) / np.sqrt(noise))[finite]))
        if not worst <= MAX_MAGNITUDE:
            raise InvalidInputError(
                f"{what} holds a velocity {worst:.3g} noise standard deviations from the mean, beyond the "
                f"{MAX_MAGNITUDE:g} whose squared term stays finite; convert the velocities to sensible units or raise noise_var"
            )


def as_headings(name: str, h: object, n: int) -> np.ndarray | None:
    """``None``, or one heading per point as contiguous float64 (``NaN``: unknown; an infinite
    heading is an :class:`~dpgp.InvalidInputError`, a wrong length a :class:`~dpgp.ShapeError`)."""
    if h is None:
        return None
    arr = np.ascontiguousarray(as_float_array(name, h), dtype=np.float64)
    if arr.shape != (n,):
        raise ShapeError(f"{name} must hold one heading per point, shape ({n},), got {arr.shape}")
    if np.isinf(arr).any():
        raise InvalidInputError(
            f"{name} holds an infinite heading; give radians, or NaN where a vehicle has no previous step"
        )
    return arr


def log_marginal_likelihood(xy: object, v: object, params: GPParams, h: object = None) -> float:
    """``log p(v | xy, h)`` summed over both outputs; ``xy`` and ``v`` have shape ``(n, 2)``, ``h``
    (optional) the previous headings, shape ``(n,)``. Velocities too far from the mean for a
    finite log density raise :class:`~dpgp.InvalidInputError` (:func:`check_scales`)."""
    v = as_pairs("v", v)
    check_scales(v, params, "v")
    xy = as_pairs("xy", xy)
    return _core.log_marginal_likelihood(xy, v, params.as_tuple(), as_headings("h", h, len(xy)), params.heading_scale)


def log_predictive(
    train_xy: object,
    train_v: object,
    test_xy: object,
    test_v: object,
    params: GPParams,
    train_h: object = None,
    test_h: object = None,
) -> float:
    """Joint log density of the test velocities given the training data (both outputs).

    Equals ``log_marginal_likelihood(train ∪ test) - log_marginal_likelihood(train)``: the score
    of a frame against a motion pattern.
    """
    train_v, test_v = as_pairs("train_v", train_v), as_pairs("test_v", test_v)
    check_scales(train_v, params, "train_v")
    check_scales(test_v, params, "test_v")
    train_xy, test_xy = as_pairs("train_xy", train_xy), as_pairs("test_xy", test_xy)
    return _core.log_predictive(
        train_xy, train_v, test_xy, test_v, params.as_tuple(),
        as_headings("train_h", train_h, len(train_xy)), as_headings("test_h", test_h, len(test_xy)),
        params.heading_scale,
    )  # fmt: skip


def log_predictive_frames(
    train_xy: object, train_v: object, test_xy: object, test_v: object, offsets: object, params: GPParams
) -> np.ndarray:
    """:func:`log_predictive` of each test frame on its own (rows ``offsets[i]:offsets[i + 1]`` of
    ``test_xy`` and ``test_v``) given the same training data, from one factorisation of it."""
    train_v, test_v = as_pairs("train_v", train_v), as_pairs("test_v", test_v)
    check_scales(train_v, params, "train_v")
    check_scales(test_v, params, "test_v")
    offsets = np.ascontiguousarray(offsets, dtype=np.int64)
    if offsets.ndim != 1:
        raise ShapeError(f"offsets must be one-dimensional, got shape {offsets.shape}")
    return _core.log_predictive_frames(
        as_pairs("train_xy", train_xy), train_v, as_pairs("test_xy", test_xy), test_v, offsets, params.as_tuple()
    )


def posterior(
    train_xy: object,
    train_v: object,
    query_xy: object,
    params: GPParams,
    train_h: object = None,
    query_h: object = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Posterior mean and variance of the noise-free velocity field at ``query_xy`` (and the
    previous headings ``query_h``, for a field over heading).

    Returns ``(mean, var)``, each of shape ``(m, 2)`` (columns ``vx``, ``vy``). Add
    ``params.noise_var`` to ``var`` for the variance of a new observed velocity.
    """
    train_v = as_pairs("train_v", train_v)
    check_scales(train_v, params, "train_v")
    train_xy, query_xy = as_pairs("train_xy", train_xy), as_pairs("query_xy", query_xy)
    return _core.posterior(
        train_xy, train_v, query_xy, params.as_tuple(),
        as_headings("train_h", train_h, len(train_xy)), as_headings("query_h", query_h, len(query_xy)),
        params.heading_scale,
    )  # fmt: skip


__all__ = [
    "GPParams",
    "check_scales",
    "log_marginal_likelihood",
    "log_predictive",
    "log_predictive_frames",
    "posterior",
]
