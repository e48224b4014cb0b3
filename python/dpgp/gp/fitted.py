"""What the modules below the estimator need of a fitted mixture, without the estimator.

:class:`~dpgp.DPGP` hands a :class:`FittedPatterns` down to :mod:`dpgp.simulation` and
:mod:`dpgp.scenarios` (``model._fitted()``), so that dependencies run one way: the estimator
imports them, never the reverse. It holds the core sampler and the patterns in the estimator's
order (by decreasing size), the training frames and the DP weights.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._constants import DEFAULT_DT
from ..data.frames import Frames


@dataclass(frozen=True, eq=False)
class FittedPatterns:
    """A fitted mixture's state: ``sampler`` (the core sampler), ``slots[k]`` (its slot of
    pattern ``k``), ``slot_order`` (pattern ``k``'s index in the core's slot order), the training
    ``frames`` and their ``labels``, the pattern ``weights`` and ``alpha``. ``cache`` is shared
    with the estimator (for φ and ψ). ``new_sampler(frames)``: a core sampler over other frames
    with the fit's settings (the estimator's own constructor), for :meth:`conditioned_on`."""

    sampler: Any
    slots: np.ndarray
    slot_order: np.ndarray
    frames: Frames
    labels: np.ndarray
    weights: np.ndarray
    alpha: float
    cache: dict = field(default_factory=dict)
    new_sampler: Callable[[Frames], Any] | None = None
    #: Whether the fields take the previous heading: frames are scored with theirs.
    headed: bool = False

    @property
    def n_patterns(self) -> int:
        return len(self.slots)

    @property
    def dt(self) -> float:
        """The training frames' time step (``make_frames`` records it), else :data:`DEFAULT_DT`."""
        return frames_dt(self.frames)

    @property
    def roi(self) -> tuple[float, float, float, float]:
        """The ROI the training frames were cropped to, else their bounding box; an axis along
        which the positions span nothing (one vehicle, vehicles on one line) is widened by the
        patterns' largest length scale on it, the reach of the fitted fields, so that vehicles
        simulated from there have room to move."""
        patterns = self.sampler.patterns()  # (slot, id, n_frames, wx, wy)
        reach = (max(p[3] for p in patterns), max(p[4] for p in patterns)) if patterns else (1.0, 1.0)
        return _widened(frames_roi(self.frames), reach)

    def log_scores(self, frames: Frames, h: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """log p(V_f | D_k) for each frame and pattern (estimator order), and the new-pattern term;
        a fit over heading takes the frames' ``prev_heading``, or ``h`` (n,) when given."""
        if self.headed and h is None:
            if frames.prev_heading is None:
                from ..exceptions import InvalidInputError

                raise InvalidInputError(
                    "the model's fields take each vehicle's previous heading: score frames made by dpgp.make_frames "
                    "from tracks, which carry it"
                )
            h = frames.prev_heading
        per_slot, new = self.sampler.score_frames(frames.xy, frames.v, frames.offsets, h if self.headed else None)
        scores = np.asarray(per_slot, dtype=np.float64).reshape(len(frames), -1)[:, self.slot_order]
        return scores, np.asarray(new, dtype=np.float64)

    def log_joint_terms(self, frames: Frames, h: np.ndarray | None = None) -> np.ndarray:
        """(N, K+1): log [DP predictive weight × likelihood] of each pattern, then of a new one."""
        scores, new = self.log_scores(frames, h)
        n = len(self.labels)
        log_prior = np.log(np.r_[self.weights * n, self.alpha]) - np.log(n + self.alpha)
        return np.column_stack([scores, new]) + log_prior

    def predict(self, frames: Frames, h: np.ndarray | None = None) -> np.ndarray:
        """The most probable existing pattern of each frame (``h``: as :meth:`log_scores`)."""
        return np.argmax(self.log_joint_terms(frames, h)[:, :-1], axis=1)

    def conditioned_on(self, rows: np.ndarray) -> tuple[FittedPatterns, np.ndarray] | None:
        """The same patterns (assignments, length scales, α, noise) conditioned on the training
        frames ``rows`` only: the fields a frame outside ``rows`` would meet as a new one. Returns
        that fit (its patterns are those with a frame among ``rows``, in this fit's order) and
        ``present``, its patterns' indices here; ``None`` without :attr:`new_sampler`."""
        if self.new_sampler is None or len(rows) == 0:
            return None
        frames, labels = self.frames[rows], self.labels[rows]
        present, compact = np.unique(labels, return_inverse=True)
        theirs = self.sampler.patterns()  # (slot, id, n_frames, wx, wy), core slot order
        ls = np.array([theirs[int(self.slot_order[k])][3:5] for k in present], dtype=np.float64).reshape(-1, 2)
        sampler = self.new_sampler(frames)
        sampler.set_noise_var(tuple(float(x) for x in self.sampler.noise_var()))
        own = np.asarray(self.sampler.pattern_noise(), dtype=np.float64).reshape(-1, 2)
        noise = np.array([own[int(self.slot_order[k])] for k in present], dtype=np.float64).reshape(-1, 2)
        wh = None
        if self.headed:
            scales = self.sampler.heading_scales()
            wh = [float(scales[int(self.slot_order[k])]) for k in present]
        sampler.set_state(compact.astype(np.int64), ls, float(self.alpha), noise, heading_scales=wh)  # own noise
        mine = sampler.patterns()  # set_state keeps label c in slot order c
        counts = np.bincount(compact, minlength=len(present)).astype(np.float64)
        sub = FittedPatterns(
            sampler, np.array([p[0] for p in mine], dtype=np.int64), np.arange(len(mine), dtype=np.int64), frames,
            compact.astype(np.int64), counts / counts.sum(), float(self.alpha), {}, self.new_sampler, self.headed,
        )  # fmt: skip
        return sub, present


def frames_dt(frames: Frames) -> float:
    dt = getattr(getattr(frames, "summary", None), "dt", None)
    return float(dt) if dt else DEFAULT_DT


def frames_roi(frames: Frames) -> tuple[float, float, float, float]:
    roi = getattr(getattr(frames, "summary", None), "roi", None)
    return tuple(float(v) for v in roi) if roi is not None else frames.bounds()  # type: ignore[return-value]


def _widened(roi: tuple[float, float, float, float], pad: tuple[float, float]) -> tuple[float, float, float, float]:
    """``roi`` with each axis of zero width widened by ``pad`` on both sides."""
    x0, x1, y0, y1 = roi
    if not x1 > x0:
        x0, x1 = x0 - pad[0], x1 + pad[0]
    if not y1 > y0:
        y0, y1 = y0 - pad[1], y1 + pad[1]
    return (x0, x1, y0, y1)


def as_fitted(obj: Any) -> FittedPatterns:
    """``obj`` itself, or what a fitted estimator hands down (anything with ``_fitted()``)."""
    if isinstance(obj, FittedPatterns):
        return obj
    fitted = getattr(obj, "_fitted", None)
    if fitted is None:
        raise TypeError(f"expected a fitted dpgp.DPGP or FittedPatterns, got {type(obj).__name__}")
    return fitted()


__all__ = ["FittedPatterns", "as_fitted", "frames_dt", "frames_roi", "DEFAULT_DT"]
