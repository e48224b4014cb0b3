"""Input coercion shared by the public functions: turn array-likes into the C-contiguous float64
arrays the Rust core borrows without copying, with errors that name the argument."""

from __future__ import annotations

import numpy as np

from . import _core
from .exceptions import InvalidInputError, ShapeError

#: Largest magnitude of a velocity, a centred position or a length scale whose squares and
#: sums stay finite in double precision, with room to spare (fits refuse larger values; model
#: files holding them are damaged).
MAX_MAGNITUDE = 1e100
#: Smallest length scale whose square is still a normal double (the core's lower limit of the
#: length-scale prior's mean, rust/core/src/gibbs.rs).
MIN_LENGTH_SCALE: float = _core.LENGTH_SCALE_MEAN_RANGE[0]
#: Range of the DP concentration α a fit accepts (and a model file may hold): the log joint's
#: ``log Γ(α) - log Γ(α + N)``, ``-1/(2α)`` and the new-pattern weight ``log(α / m)`` stay finite.
#: The core's limit (rust/core/src/gibbs.rs), which checks a fit's α itself.
ALPHA_RANGE: tuple[float, float] = _core.ALPHA_RANGE


def alpha_in_range(alpha: object) -> bool:
    """Whether ``alpha`` is a real number (not a bool) inside :data:`ALPHA_RANGE`."""
    if isinstance(alpha, bool) or not isinstance(alpha, (int, float, np.integer, np.floating)):
        return False
    try:
        return ALPHA_RANGE[0] <= float(alpha) <= ALPHA_RANGE[1]
    except OverflowError:  # an int past the float range
        return False


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


def is_path(value: object) -> bool:
    """A file path as Python takes one: ``str``, ``bytes`` or an ``os.PathLike``."""
    import os

    return isinstance(value, (str, bytes, os.PathLike))


def as_path(value: object) -> str:
    """``value`` (``str``, ``bytes`` or ``os.PathLike``) as a ``str`` path; bytes are decoded
    as ``os.fsdecode`` does, so every byte name round-trips. ``TypeError`` for anything that is
    not a path at all, as ``open`` raises."""
    import os

    if not is_path(value):
        raise TypeError(f"expected a file path (str, bytes or os.PathLike), got {type(value).__name__}")
    return os.fsdecode(os.fspath(value))  # type: ignore[call-overload]  # is_path checked it


def column_floats(values: object, name: object, where: str = "") -> np.ndarray:
    """A table column (a pandas Series or array) as float64, where an integer too large for a
    double (past 1.8e308) is a :class:`~dpgp.DataFormatError` naming the column and row rather
    than Python's ``OverflowError``."""
    from .exceptions import DataFormatError

    arr = values.to_numpy() if hasattr(values, "to_numpy") else np.asarray(values)
    try:
        return np.asarray(arr, dtype=np.float64)
    except OverflowError:
        pass
    out = np.empty(len(arr))
    for i, x in enumerate(arr):
        try:
            out[i] = float(x)
        except OverflowError:
            raise DataFormatError(
                f"{where + ': ' if where else ''}column {name!r} holds a number too large for a double "
                f"(beyond 1.8e308) at row {i}: {str(x)[:20]}...; is this the right column?"
            ) from None
        except (TypeError, ValueError):
            out[i] = np.nan  # reported by the caller's check of missing values
    return out


def compact_labels(labels: object) -> np.ndarray:
    """Non-negative integer labels in the smallest unsigned type that holds them (a copy): 10
    million frames' patterns, under 256 of them, take 10 MB rather than 80."""
    a = np.asarray(labels)
    top = int(a.max()) if a.size else 0
    return a.astype(np.min_scalar_type(max(top, 0)))
