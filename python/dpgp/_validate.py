"""Argument checks shared across stages: one rule each, with the error that says what to fix."""

from __future__ import annotations

from typing import Any

import numpy as np

from .exceptions import InvalidInputError

ROI = tuple[float, float, float, float]


def real_number(name: str, value: Any) -> float:
    """``value`` as a float: a real number (not a bool or a string) that a float can hold."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InvalidInputError(f"{name} must be a number, got {value!r}")
    try:
        return float(value)
    except OverflowError:  # an int beyond the float range, such as 2**1024
        raise InvalidInputError(
            f"{name} is beyond the float range (an integer of {len(str(abs(value)))} digits)"
        ) from None


def check_roi(roi: Any, name: str = "roi") -> ROI:
    """A region of interest ``(x_min, x_max, y_min, y_max)``: four real numbers (not bools or
    strings), finite, with ``x_min < x_max`` and ``y_min < y_max``, and widths a float can hold
    (the empirical distributions bin over them). Returned as a tuple of floats."""
    fix = f"{name} must be (x_min, x_max, y_min, y_max), four finite numbers with x_min < x_max and y_min < y_max"
    if isinstance(roi, (str, bytes)) or not hasattr(roi, "__len__") or len(roi) != 4:
        raise InvalidInputError(f"{fix}; got {roi!r}")
    try:
        box = tuple(real_number(name, v) for v in roi)
    except InvalidInputError:
        raise InvalidInputError(f"{fix}; got {roi!r}") from None
    if not (all(np.isfinite(box)) and box[0] < box[1] and box[2] < box[3]):
        raise InvalidInputError(f"{fix}; got {roi!r}")
    if not (np.isfinite(box[1] - box[0]) and np.isfinite(box[3] - box[2])):
        raise InvalidInputError(
            f"{name} {roi!r} is wider than the floating-point range (1.8e308); convert to sensible units"
        )
    return box  # type: ignore[return-value]


def inside_roi(xy: np.ndarray, roi: ROI) -> np.ndarray:
    """Which points of ``xy`` (..., 2) lie in ``roi`` (edges included)."""
    x0, x1, y0, y1 = roi
    with np.errstate(invalid="ignore"):  # NaN positions (vehicles not recorded) are outside
        return (xy[..., 0] >= x0) & (xy[..., 0] <= x1) & (xy[..., 1] >= y0) & (xy[..., 1] <= y1)


__all__ = ["check_roi", "inside_roi", "real_number"]
