"""Held-out scores of pattern dynamics (issue 20): does the order of frames carry information the
independent model (the paper's DP, frames exchangeable) misses?

For held-out frames in time order, two numbers each under the learned transitions (an HMM over the
fit's patterns plus "a new pattern") and under the independent model:

- the log-likelihood of the label sequence (each held-out frame's most probable pattern);
- the velocity density per vehicle of frame ``t`` given the frames before it: the HMM forward
  pass, ``log p(x_t | x_<t)``, against the independent mixture ``log p(x_t)``.

The HMM's rows are the learned transition counts shrunk toward the DP's predictive weights:
``A[i] = (counts[i] + c · π) / (n_i + c)`` with ``c = smoothing`` pseudo-frames, ``π`` the
predictive weights (``n_k / (n + α)`` and ``α / (n + α)`` for a new pattern), which are also the
independent model and the HMM's start and new-pattern rows. Emissions are the fitted state's
collapsed predictive densities (the final state, not averaged over posterior draws)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..data.timeorder import TimeOrder, time_order
from ..exceptions import InvalidInputError


def _logsumexp(a: np.ndarray, axis: int = -1) -> np.ndarray:
    """log Σ exp along ``axis``; -inf where every term is -inf."""
    m = np.max(a, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    with np.errstate(divide="ignore"):
        return np.squeeze(m, axis) + np.log(np.sum(np.exp(a - m), axis=axis))


def forward_log_likelihoods(
    log_emission: np.ndarray, log_a: np.ndarray, log_start: np.ndarray, order: TimeOrder
) -> np.ndarray:
    """``log p(x_t | x_<t)`` of each frame under an HMM (forward pass along each unbroken run of
    consecutive frames; a run starts from ``log_start``). ``log_emission``: (N, S)."""
    out = np.empty(len(order))
    for seq in order.sequences():
        alpha = log_start + log_emission[seq[0]]  # log p(z_t, x_≤t) before normalising
        out[seq[0]] = _logsumexp(alpha)
        alpha = alpha - out[seq[0]]
        for t in seq[1:]:
            alpha = _logsumexp(alpha[:, None] + log_a, axis=0) + log_emission[t]
            out[t] = _logsumexp(alpha)
            alpha = alpha - out[t]
    return out


@dataclass(frozen=True)
class SequenceScores:
    """Held-out dynamics scores (nats); ``*_markov`` under the learned transitions, ``*_independent``
    under the DP weights alone. ``label_*``: per held-out frame; ``density_*``: per vehicle."""

    label_markov: float
    label_independent: float
    density_markov: float
    density_independent: float
    n_frames: int
    n_vehicles: int
    n_runs: int
    #: the label sequence under the fit's phases (:mod:`.phases`; NaN when none were given)
    label_phases: float = float("nan")

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def sequence_scores(
    model: Any, test_frames: Any, smoothing: float = 1.0, dt: float | None = None, phases: Any = None
) -> SequenceScores:
    """:class:`SequenceScores` of ``test_frames`` (frames with times) under a fitted ``model``'s
    transitions (``model.transitions_``) against its independent DP weights; with ``phases``
    (:class:`dpgp.evaluate.phases.Phases` of the model) also the label sequence's log-likelihood
    per frame under the phases' HMM (forward pass)."""
    if not (isinstance(smoothing, (int, float)) and np.isfinite(smoothing) and smoothing > 0):
        raise InvalidInputError(f"smoothing must be a positive number of pseudo-frames, got {smoothing!r}")
    order = time_order(test_frames, dt)
    tr = model.transitions_
    fitted = model._fitted()
    k = model.n_patterns_
    n = len(model.labels_)
    pi = np.r_[np.bincount(model.labels_, minlength=k), model.alpha_] / (n + model.alpha_)
    a = np.zeros((k + 1, k + 1))
    a[:k, :k] = tr.counts
    row = a.sum(1, keepdims=True)
    a = (a + smoothing * pi) / (row + smoothing)
    a[k] = pi  # from a new pattern: the DP weights
    scores, new = fitted.log_scores(test_frames)
    log_e = np.column_stack([scores, new])  # log p(x_t | pattern), the last column a new pattern
    log_pi, log_a = np.log(pi), np.log(a)
    indep = _logsumexp(log_e + log_pi)
    markov = forward_log_likelihoods(log_e, log_a, log_pi, order)
    z = np.argmax(scores + log_pi[:k], axis=1)  # each held-out frame's most probable pattern
    lab_m = log_pi[z].copy()
    has_prev = order.prev >= 0
    lab_m[has_prev] = log_a[z[order.prev[has_prev]], z[has_prev]]
    sizes = np.diff(np.asarray(test_frames.offsets))
    lab_p = float("nan")
    if phases is not None:
        lab_p = phases.sequence_log_likelihood([z[s] for s in order.sequences()]) / len(order)
    return SequenceScores(
        float(lab_m.mean()), float(log_pi[z].mean()), float(markov.sum() / sizes.sum()),
        float(indep.sum() / sizes.sum()), len(order), int(sizes.sum()), len(order.sequences()), lab_p,
    )  # fmt: skip


__all__ = ["SequenceScores", "forward_log_likelihoods", "sequence_scores"]
