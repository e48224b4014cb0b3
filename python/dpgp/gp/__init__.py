"""Stage 2, the velocity-field math everything above shares: the exact GP (:mod:`.exact`, whose
public functions are this package's, so ``dpgp.gp.log_marginal_likelihood`` keeps working), its
reduced-rank approximation (:mod:`.hsgp`), the data-driven defaults of a fit (:mod:`.defaults`),
the kept posterior draws (:mod:`.draws`) and the snapshot of a fit that generation, evaluation and
model files need (:mod:`.fitted`)."""

from . import defaults, draws, exact, fitted, hsgp
from .exact import GPParams, check_scales, log_marginal_likelihood, log_predictive, log_predictive_frames, posterior

__all__ = [
    "GPParams",
    "check_scales",
    "log_marginal_likelihood",
    "log_predictive",
    "log_predictive_frames",
    "posterior",
]
