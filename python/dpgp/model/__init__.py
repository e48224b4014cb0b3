"""Stage 6, the estimator: :class:`.estimator.DPGP` and the cost model that picks its likelihood
engine (:mod:`.engine_cost`)."""

from . import engine_cost, estimator
from .estimator import DPGP, MIN_NOISE_RATIO

__all__ = ["DPGP", "MIN_NOISE_RATIO"]
