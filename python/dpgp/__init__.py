"""dpgp: learn multi-vehicle motion patterns from traffic data and generate scenarios from them.

A Dirichlet-process mixture of Gaussian-process velocity fields (Guo, Kalidindi et al., "Modeling
Multi-Vehicle Interaction Scenarios Using Gaussian Random Field"), fitted by collapsed Gibbs
sampling in a Rust core.
"""

from . import _core, datasets, diagnostics, gp, hsgp, partition, plot
from .chains import Chains, ChainsFailedError, fit_chains
from .exceptions import (
    DataFormatError,
    DpgpError,
    InvalidInputError,
    MemoryBudgetError,
    ModelFileError,
    NotFittedError,
    NotPositiveDefiniteError,
    ShapeError,
)
from .distributions import EmpiricalDistributions
from .frames import Frame, Frames, read_frames
from .framing import FramingSummary, make_frames, resample_tracks
from .gp import GPParams
from .metrics import adjusted_rand_index
from .model import DPGP
from .scenarios import Scenarios
from .simulation import Simulation
from .tracks import read_ngsim, read_tracks
from . import evaluate, realism  # dpgp.evaluate.realism(...) without importing the module first

__version__: str = _core.__version__

__all__ = [
    "DPGP",
    "Chains",
    "ChainsFailedError",
    "fit_chains",
    "diagnostics",
    "partition",
    "DataFormatError",
    "DpgpError",
    "Frame",
    "Frames",
    "GPParams",
    "InvalidInputError",
    "MemoryBudgetError",
    "ModelFileError",
    "NotFittedError",
    "NotPositiveDefiniteError",
    "ShapeError",
    "datasets",
    "gp",
    "hsgp",
    "plot",
    "Scenarios",
    "Simulation",
    "read_frames",
    "EmpiricalDistributions",
    "FramingSummary",
    "make_frames",
    "read_ngsim",
    "read_tracks",
    "resample_tracks",
    "adjusted_rand_index",
]
__all__ += ["evaluate", "realism"]
