"""Named constants that more than one module uses (one home, so that they cannot drift apart)."""

from __future__ import annotations

#: Seconds between frames when the data do not say: the paper's time step. ``make_frames``
#: frames trajectories at it by default; simulations and generation fall back to it.
DEFAULT_DT = 0.5

#: Share of the frames, first in time, that a split in time trains on (the rest is held out):
#: ``dpgp.evaluate.split_in_time``, ``dpgp evaluate --split`` and the held-out pilots of the
#: data-driven defaults (``noise_var="auto"``, the single-GP baseline's grid).
TRAIN_FRACTION = 0.7

#: Posterior / prior variance above which a point of a rollout counts as low-data (the field
#: there is mostly the prior).
LOW_DATA_THRESHOLD = 0.5

#: Metres in an international foot (NGSIM and other US recordings give feet).
FT_TO_M = 0.3048

__all__ = ["DEFAULT_DT", "TRAIN_FRACTION", "LOW_DATA_THRESHOLD", "FT_TO_M"]
