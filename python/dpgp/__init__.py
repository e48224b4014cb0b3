"""dpgp: learn multi-vehicle motion patterns from traffic data and generate scenarios from them.

A Dirichlet-process mixture of Gaussian-process velocity fields (Guo, Kalidindi et al., "Modeling
Multi-Vehicle Interaction Scenarios Using Gaussian Random Field"), fitted by collapsed Gibbs
sampling in a Rust core.
"""

from . import _core, gp
from .exceptions import (
    DataFormatError,
    DpgpError,
    InvalidInputError,
    ModelFileError,
    NotFittedError,
    NotPositiveDefiniteError,
    ShapeError,
)
from .frames import Frame, Frames, read_frames
from .gp import GPParams

__version__: str = _core.__version__

__all__ = [
    "DataFormatError",
    "DpgpError",
    "Frame",
    "Frames",
    "GPParams",
    "InvalidInputError",
    "ModelFileError",
    "NotFittedError",
    "NotPositiveDefiniteError",
    "ShapeError",
    "gp",
    "read_frames",
]
