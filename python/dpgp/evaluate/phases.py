"""Phases of a scene: persistent regimes above the patterns (issue 20).

A pattern is one velocity field, and a scene's regime is often a sequence of several: a signal
phase of the SUMO junction is a queue-discharge field for its first ~15 s and a queued field after
(docs/dynamics.md), and no stickiness of one frame's label makes those one pattern. A *phase* here
is a hidden state over the fit's pattern labels in time order: a hidden Markov model whose state
``r_t`` emits the frame's pattern ``z_t`` from its own distribution over patterns (the sticky
HDP-HMM with mixture emissions of Fox et al., Ann. Appl. Stat. 2011, with a fixed number of
states). Patterns may be shared by phases (a discharge field by both directions); the phases'
persistence and order place them.

Fitted by Baum–Welch (EM) from several starts, decoded by Viterbi. The number of phases is given,
or ``"auto"``: the one of ``1..max_phases`` with the lowest BIC. Long scenarios
(:mod:`dpgp.generate.long`) switch phase by the decoded phases' transitions and recorded
durations, and within a phase switch pattern only as that phase's frames did, so that the fields
in force stay those of one regime.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..data.timeorder import TimeOrder, time_order
from ..exceptions import InvalidInputError
from .transitions import Transitions, count_transitions

#: Pseudo-counts of the M-step (emissions, transitions, starts): no probability reaches 0.
SMOOTHING = 1e-3
MAX_PHASES = 6


@dataclass(frozen=True, eq=False)
class Phases:
    """Phases of a fit's frames.

    ``labels``: each frame's phase (Viterbi path), phases numbered by size, largest first;
    ``emission`` (P, K): each phase's distribution over the patterns; ``trans`` (P, P) and
    ``start`` (P,): the HMM's transition and start probabilities; ``log_likelihood`` of the
    pattern sequence under the HMM; ``bic`` per number of phases tried; ``transitions``: the
    :class:`Transitions` of the phase labels (runs, dwell times, share kept); ``within``
    (P, K, K): consecutive frame pairs with patterns ``i`` then ``j`` inside one phase's runs;
    ``pattern_runs``: per phase, ``(pattern, n_frames)`` of every pattern run inside its runs."""

    labels: np.ndarray
    emission: np.ndarray
    trans: np.ndarray
    start: np.ndarray
    log_likelihood: float
    bic: dict[int, float]
    transitions: Transitions
    within: np.ndarray
    pattern_runs: list[np.ndarray]

    @property
    def n_phases(self) -> int:
        return len(self.start)

    def summary(self) -> str:
        tr = self.transitions
        d = tr.dwell()
        share = np.bincount(self.labels, minlength=self.n_phases) / max(len(self.labels), 1)
        md = tr.mean_dwell()
        lines = [
            f"phases: {self.n_phases} (BIC by count: "
            + ", ".join(f"{p}: {b:.0f}" for p, b in sorted(self.bic.items()))
            + ")",
            f"  consecutive frames share a phase {100 * tr.share_same:.1f}% of the time; runs: {len(d)}, "
            f"mean {d.mean():.1f} s, median {np.median(d):.1f} s",
        ]
        for p in range(self.n_phases):
            top = np.argsort(-self.emission[p])[:3]
            pats = ", ".join(f"{k} ({100 * self.emission[p, k]:.0f}%)" for k in top)
            lines.append(f"  phase {p}: {100 * share[p]:.1f}% of frames, mean dwell {md[p]:.1f} s; patterns {pats}")
        return "\n".join(lines)


def _forward_backward(
    z: np.ndarray, log_b: np.ndarray, a: np.ndarray, pi: np.ndarray
) -> tuple[float, np.ndarray, np.ndarray]:
    """One sequence ``z``: log-likelihood, state posteriors (T, P) and summed pair posteriors
    (P, P), by the scaled forward–backward recursions."""
    b = np.exp(log_b[:, z].T)  # (T, P) emission probabilities
    n, p = b.shape
    alpha = np.empty((n, p))
    c = np.empty(n)
    x = pi * b[0]
    c[0] = x.sum()
    alpha[0] = x / c[0]
    for t in range(1, n):
        x = (alpha[t - 1] @ a) * b[t]
        c[t] = x.sum()
        alpha[t] = x / c[t]
    beta = np.empty((n, p))
    beta[-1] = 1.0
    for t in range(n - 2, -1, -1):
        beta[t] = a @ (b[t + 1] * beta[t + 1]) / c[t + 1]
    gamma = alpha * beta
    xi = np.zeros((p, p))
    if n > 1:
        xi = a * ((alpha[:-1] / c[1:, None]).T @ (b[1:] * beta[1:]))
    return float(np.log(c).sum()), gamma, xi


def hmm_log_likelihood(seqs: list[np.ndarray], emission: np.ndarray, trans: np.ndarray, start: np.ndarray) -> float:
    """Log-likelihood of the label sequences ``seqs`` under the HMM (forward pass)."""
    log_b = np.log(emission)
    return float(sum(_forward_backward(z, log_b, trans, start)[0] for z in seqs))


def viterbi(z: np.ndarray, emission: np.ndarray, trans: np.ndarray, start: np.ndarray) -> np.ndarray:
    """The most probable state path of one label sequence ``z``."""
    log_b, log_a = np.log(emission), np.log(trans)
    n, p = len(z), len(start)
    back = np.zeros((n, p), dtype=np.int64)
    d = np.log(start) + log_b[:, z[0]]
    for t in range(1, n):
        x = d[:, None] + log_a
        back[t] = np.argmax(x, axis=0)
        d = x[back[t], np.arange(p)] + log_b[:, z[t]]
    path = np.empty(n, dtype=np.int64)
    path[-1] = int(np.argmax(d))
    for t in range(n - 1, 0, -1):
        path[t - 1] = back[t, path[t]]
    return path


def _em(
    seqs: list[np.ndarray], p: int, k: int, rng: np.random.Generator, max_iter: int, tol: float
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    emission = rng.dirichlet(np.ones(k), size=p)
    trans = np.full((p, p), 0.05 / max(p - 1, 1))  # persistent from the start: phases, not frames
    np.fill_diagonal(trans, 0.95 if p > 1 else 1.0)
    start = np.full(p, 1.0 / p)
    log_b = np.log(emission)
    prev = -np.inf
    ll = -np.inf
    for _ in range(max_iter):
        nb = np.zeros((p, k))
        na = np.zeros((p, p))
        n0 = np.zeros(p)
        ll = 0.0
        for z in seqs:
            lz, gamma, xi = _forward_backward(z, log_b, trans, start)
            ll += lz
            np.add.at(nb.T, z, gamma)
            na += xi
            n0 += gamma[0]
        emission = (nb + SMOOTHING) / (nb + SMOOTHING).sum(axis=1, keepdims=True)
        trans = (na + SMOOTHING) / (na + SMOOTHING).sum(axis=1, keepdims=True)
        start = (n0 + SMOOTHING) / (n0 + SMOOTHING).sum()
        log_b = np.log(emission)
        if ll - prev < tol * abs(ll):
            break
        prev = ll
    ll = hmm_log_likelihood(seqs, emission, trans, start)
    return ll, emission, trans, start


def _n_params(p: int, k: int) -> int:
    return (p - 1) + p * (p - 1) + p * (k - 1)


def fit_phases(
    labels: Any,
    order: TimeOrder | Any,
    n_phases: int | str = 2,
    *,
    n_patterns: int | None = None,
    seed: int | None = 0,
    restarts: int = 4,
    max_phases: int = MAX_PHASES,
    max_iter: int = 200,
    tol: float = 1e-7,
) -> Phases:
    """The :class:`Phases` of frame ``labels`` (integers ``0..K-1``) in the time ``order`` of their
    frames (a :class:`TimeOrder`, or the frames). ``n_phases``: a positive integer, or ``"auto"``
    (lowest BIC of ``1..max_phases``). EM from ``restarts`` random emissions (``seed``), the best
    log-likelihood kept. :class:`~dpgp.exceptions.UnorderedFramesError` for frames without times."""
    if not isinstance(order, TimeOrder):
        order = time_order(order)
    labels = np.asarray(labels)
    if labels.shape != (len(order),) or (len(labels) and (labels.dtype.kind not in "iu" or labels.min() < 0)):
        raise InvalidInputError(f"labels must be {len(order)} non-negative integers, one per frame")
    if not len(labels):
        raise InvalidInputError("phases need at least one frame")
    auto = isinstance(n_phases, str)
    if auto and n_phases != "auto":
        raise InvalidInputError(f"n_phases must be a positive integer or 'auto', got {n_phases!r}")
    if not auto and (isinstance(n_phases, bool) or not isinstance(n_phases, (int, np.integer)) or n_phases < 1):
        raise InvalidInputError(f"n_phases must be a positive integer or 'auto', got {n_phases!r}")
    if isinstance(restarts, bool) or not isinstance(restarts, (int, np.integer)) or restarts < 1:
        raise InvalidInputError(f"restarts must be a positive integer, got {restarts!r}")
    labels = labels.astype(np.int64)
    k = int(max(n_patterns or 0, labels.max() + 1))
    seqs_idx = order.sequences()
    seqs = [labels[s] for s in seqs_idx]
    counts = range(1, max_phases + 1) if auto else [int(n_phases)]
    rng = np.random.default_rng(seed)
    fits: dict[int, tuple[float, np.ndarray, np.ndarray, np.ndarray]] = {}
    bic: dict[int, float] = {}
    for p in counts:
        best = max(
            (_em(seqs, p, k, rng, max_iter, tol) for _ in range(int(restarts) if p > 1 else 1)), key=lambda r: r[0]
        )
        fits[p] = best
        bic[p] = -2.0 * best[0] + _n_params(p, k) * np.log(len(labels))
    p = min(bic, key=lambda q: bic[q]) if auto else int(n_phases)
    ll, emission, trans, start = fits[p]
    path = np.empty(len(labels), dtype=np.int64)
    for s, z in zip(seqs_idx, seqs):
        path[s] = viterbi(z, emission, trans, start)
    # number phases by size, largest first (a deterministic name for each)
    rank = np.argsort(-np.bincount(path, minlength=p), kind="stable")
    new = np.empty(p, dtype=np.int64)
    new[rank] = np.arange(p)
    path = new[path]
    emission, start, trans = emission[rank], start[rank], trans[np.ix_(rank, rank)]
    within = np.zeros((p, k, k), dtype=np.int64)
    has_next = (order.next >= 0) & (path[np.maximum(order.next, 0)] == path)
    np.add.at(within, (path[has_next], labels[has_next], labels[order.next[has_next]]), 1)
    pattern_runs: list[list[tuple[int, int]]] = [[] for _ in range(p)]
    for s in seqs_idx:
        lab, ph = labels[s], path[s]
        cut = np.flatnonzero((np.diff(lab) != 0) | (np.diff(ph) != 0)) + 1
        for a, b in zip(np.r_[0, cut], np.r_[cut, len(s)]):
            pattern_runs[int(ph[a])].append((int(lab[a]), int(b - a)))
    return Phases(
        labels=path,
        emission=emission,
        trans=trans,
        start=start,
        log_likelihood=float(ll),
        bic=bic,
        transitions=count_transitions(path, order, p),
        within=within,
        pattern_runs=[np.asarray(r, dtype=np.int64).reshape(-1, 2) for r in pattern_runs],
    )


__all__ = ["Phases", "fit_phases", "hmm_log_likelihood", "viterbi", "MAX_PHASES"]
