"""Stage 4, evaluation: held-out scores against baselines (:mod:`.scores`, whose public names are
this package's, so ``dpgp.evaluate.evaluate(...)`` and ``dpgp.evaluate.realism(...)`` keep
working; the closed-form density baselines are in :mod:`.baselines`), partition metrics
(:mod:`.metrics`) and the realism of generated scenarios (:mod:`.realism_checks`, named so that
it does not shadow the ``realism`` function)."""

from . import baselines, metrics, realism_checks, scores
from .realism_checks import Realism, model_realism
from .scores import (
    LENGTH_GRID,
    METHODS,
    SINGLE_GP_POINTS,
    TRAIN_FRACTION,
    ConstantVelocity,
    Evaluation,
    SingleGP,
    constant_velocity_scores,
    evaluate,
    position_blind_scores,
    realism,
    rollout_errors,
    split_in_time,
)

__all__ = [
    "Evaluation", "evaluate", "realism", "split_in_time", "SingleGP", "position_blind_scores", "rollout_errors",
    "constant_velocity_scores", "ConstantVelocity",
    "TRAIN_FRACTION", "LENGTH_GRID", "METHODS", "SINGLE_GP_POINTS", "Realism", "model_realism",
]  # fmt: skip
