"""Stage 7, many chains: running them locally or on Dask (:mod:`.runner`), convergence
diagnostics (:mod:`.diagnostics`) and the summary partition (:mod:`.partition`)."""

from . import diagnostics, partition, runner
from .runner import QUANTITIES, Chains, ChainsFailedError, block_seed, convergence, fit_chains

__all__ = ["fit_chains", "Chains", "ChainsFailedError", "convergence", "block_seed", "QUANTITIES"]
