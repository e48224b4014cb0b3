"""Input coercion shared by the public functions: turn array-likes into the C-contiguous float64
arrays the Rust core borrows without copying, with errors that name the argument."""

from __future__ import annotations

import numpy as np

from .exceptions import InvalidInputError, ShapeError

#: Largest magnitude of a velocity, a centred position or a length scale whose squares and
#: sums stay finite in double precision, with room to spare (fits refuse larger values; model
#: files holding them are damaged).
MAX_MAGNITUDE = 1e100
#: Smallest length scale whose square is still a normal double.
MIN_LENGTH_SCALE = 1e-150


def as_float_array(name: str, a: object) -> np.ndarray:
    try:
        return np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InvalidInputError(f"{name} must be numeric, could not convert it to float64: {e}") from None


def as_pairs(name: str, a: object) -> np.ndarray:
    """An ``(n, 2)`` C-contiguous float64 array (positions or velocities)."""
    arr = as_float_array(name, a)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ShapeError(f"{name} must have shape (n, 2), got {arr.shape}")
    return np.ascontiguousarray(arr)


def as_vector(name: str, a: object) -> np.ndarray:
    """A one-dimensional C-contiguous float64 array."""
    arr = as_float_array(name, a)
    if arr.ndim != 1:
        raise ShapeError(f"{name} must be one-dimensional, got shape {arr.shape}")
    return np.ascontiguousarray(arr)


def check_finite(name: str, a: np.ndarray) -> None:
    bad = ~np.isfinite(a)
    if bad.any():
        idx = np.flatnonzero(bad.reshape(len(a), -1).any(axis=1)) if a.ndim else np.array([0])
        raise InvalidInputError(
            f"{name} contains {int(bad.sum())} non-finite value(s) (NaN or inf), first at row {int(idx[0])}; "
            "drop or impute them first"
        )
