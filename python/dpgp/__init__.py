"""dpgp: learn multi-vehicle motion patterns from traffic data and generate scenarios from them.

A Dirichlet-process mixture of Gaussian-process velocity fields (Guo, Kalidindi et al., "Modeling
Multi-Vehicle Interaction Scenarios Using Gaussian Random Field"), fitted by collapsed Gibbs
sampling in a Rust core.

The package is laid out by pipeline stage (docs/layout.md): :mod:`dpgp.data` → :mod:`dpgp.gp` →
:mod:`dpgp.generate` → :mod:`dpgp.evaluate` → :mod:`dpgp.io` → :mod:`dpgp.model` →
:mod:`dpgp.chains`; this module re-exports the public API.
"""

import importlib as _importlib
import sys as _sys

from . import _core, chains, data, evaluate, exceptions, generate, gp, io, model, plot
from ._version import __version__
from .chains import Chains, ChainsFailedError, diagnostics, fit_chains, partition
from .data import datasets
from .data.frames import Frame, Frames, read_frames
from .data.framing import FramingSummary, make_frames, resample_tracks
from .data.linking import link_tracks
from .data.read import read
from .data.tracks import read_ngsim, read_tracks
from .evaluate.metrics import adjusted_rand_index
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
from .generate.distributions import EmpiricalDistributions
from .generate.scenarios import Scenarios
from .generate.simulation import Simulation
from .gp import GPParams, hsgp
from .model import DPGP

# The flat module names of earlier releases (dpgp.frames, dpgp.simulation, dpgp.realism, ...) still
# reach their modules, by attribute and by import, so that user code keeps working.
_MOVED = {
    "tracks": "data.tracks", "framing": "data.framing", "frames": "data.frames", "provenance": "data.provenance",
    "hsgp": "gp.hsgp", "fitted": "gp.fitted", "posterior": "gp.draws", "defaults": "gp.defaults",
    "distributions": "generate.distributions", "motion": "generate.motion", "simulation": "generate.simulation",
    "scenarios": "generate.scenarios", "openscenario": "generate.openscenario",
    "metrics": "evaluate.metrics", "realism": "evaluate.realism_checks",
    "checkpoint": "io.checkpoint", "engine_cost": "model.engine_cost",
    "datasets": "data.datasets", "diagnostics": "chains.diagnostics", "partition": "chains.partition",
}  # fmt: skip
for _old, _new in _MOVED.items():
    _module = _importlib.import_module(f"{__name__}.{_new}")
    globals()[_old] = _module
    _sys.modules[f"{__name__}.{_old}"] = _module
del _old, _new, _module

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
    "read",
    "read_frames",
    "EmpiricalDistributions",
    "FramingSummary",
    "make_frames",
    "link_tracks",
    "read_ngsim",
    "read_tracks",
    "resample_tracks",
    "adjusted_rand_index",
    "evaluate",
    "realism",
]
