"""The exceptions dpgp raises. Every one derives from :class:`DpgpError`; errors caused by bad
input also derive from :class:`ValueError`, so ``except ValueError`` keeps working."""

from __future__ import annotations

import numpy as np


class DpgpError(Exception):
    """Base class of every error raised by dpgp."""


class InvalidInputError(DpgpError, ValueError):
    """An argument or a data value is out of range (NaN, a non-positive variance, an unknown option)."""


class ShapeError(InvalidInputError):
    """Arrays whose shapes do not fit together, or an empty array where data is needed."""


class DataFormatError(InvalidInputError):
    """A table or file that is not what was expected: missing or misspelt columns, unreadable values."""


class UnorderedFramesError(InvalidInputError):
    """Frames without a recording time (ids that are not grid times or ``(scene, time)`` pairs)
    where time order is needed: transitions, dwell times, pattern dynamics."""


class NotPositiveDefiniteError(DpgpError, np.linalg.LinAlgError):
    """A covariance matrix stayed indefinite even after diagonal jitter."""


class MemoryBudgetError(DpgpError, MemoryError):
    """A fit would grow past its memory budget. Nothing was allocated and the state reached is
    kept; the message gives the estimate. ``likelihood="hsgp"`` needs far less memory."""


class NotFittedError(DpgpError, AttributeError):
    """A method that needs a fitted model was called before ``fit``."""


class ModelFileError(DpgpError, OSError):
    """A model file that is truncated, corrupted, or written by a newer dpgp."""


__all__ = [
    "DpgpError",
    "InvalidInputError",
    "ShapeError",
    "DataFormatError",
    "UnorderedFramesError",
    "NotPositiveDefiniteError",
    "MemoryBudgetError",
    "NotFittedError",
    "ModelFileError",
]
