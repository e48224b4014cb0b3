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
from .sequence import _logsumexp
from .transitions import Transitions, count_transitions

#: Pseudo-counts of the M-step (emissions, transitions, starts): no probability reaches 0.
SMOOTHING = 1e-3
MAX_PHASES = 6
#: ``durations=True``: the longest phase a model can hold (s), and the least spread of its log-normal
MAX_DURATION = 180.0
MIN_LOG_SD = 0.05
#: ``durations=True``: the starting mean durations (s) of the EM runs (each with every restart)
START_DURATIONS = (20.0, 45.0)
#: Random starts of the HMM's EM by default: on labels, and on evidence (frames' likelihoods under
#: every pattern), whose optima are more numerous (all 3,150 SUMO junction frames, 2 phases: the
#: best of 4 starts agreed with the signal on 80% of frames, of 16 on 92%). A semi-Markov fit
#: (:data:`RESTARTS` random starts, each costly) also starts from the best HMM of
#: :data:`HMM_INIT_RESTARTS` (cheap) starts.
RESTARTS = 4
EVIDENCE_RESTARTS = 16
HMM_INIT_RESTARTS = 16


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
    #: ``durations=True``: each phase's duration, a log-normal ``(mu, sd)`` of log seconds
    durations: np.ndarray | None = None
    dt: float = float("nan")
    d_max: int = 0
    #: ``cycle=True``: the phases follow one another in a fixed order, and ``cycles`` (n, P) holds
    #: each complete recorded cycle's stage durations in frames (stage 0 first), so that long
    #: scenarios draw a cycle's stages together (a decoded boundary that comes late shortens the
    #: stage after it), each cycle stretched to the recorded cycles' mean length.
    cycle: bool = False
    cycles: np.ndarray | None = None

    @property
    def n_phases(self) -> int:
        return len(self.start)

    @property
    def frame_shares(self) -> np.ndarray:
        """(P, K): each phase's frames' shares by pattern (the pattern runs inside its runs; the
        emission for a phase without frames). Long scenarios weight a phase's fields by these, not
        by its emission: fitted to the frames' likelihoods, that can give a pattern of two frames,
        whose broad posterior explains many frames moderately, a fifth of a phase (SUMO junction)."""
        k = self.emission.shape[1]
        counts = np.stack([np.bincount(r[:, 0], weights=r[:, 1], minlength=k) for r in self.pattern_runs])
        total = counts.sum(axis=1, keepdims=True)
        return np.where(total > 0, counts / np.maximum(total, 1), self.emission)

    def sequence_log_likelihood(self, seqs: list[np.ndarray]) -> float:
        """Log-likelihood of pattern label sequences (each an unbroken run of frames) under these
        phases: the HMM's forward pass, or the semi-Markov model's."""
        if self.durations is None:
            return hmm_log_likelihood(seqs, self.emission, self.trans, self.start)
        lp = duration_log_pmf(self.durations[:, 0] - np.log(self.dt), self.durations[:, 1], self.d_max)
        return _hsmm_log_likelihood(seqs, self.emission, self.trans, self.start, lp)

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
        if self.cycles is not None and len(self.cycles):
            c = self.cycles.sum(axis=1) * self.dt
            q1, q3 = np.percentile(c, [25, 75])
            lines.append(
                f"  cycle: {len(c)} complete recorded cycles, median {np.median(c):.1f} s (IQR {q1:.1f}-{q3:.1f} s)"
            )
        frames = self.frame_shares
        for p in range(self.n_phases):
            top = np.argsort(-frames[p], kind="stable")[:3]
            pats = ", ".join(f"{k} ({100 * frames[p, k]:.0f}%)" for k in top)
            lines.append(
                f"  phase {p}: {100 * share[p]:.1f}% of frames, mean dwell {md[p]:.1f} s; its frames' patterns {pats}"
            )
        return "\n".join(lines)


class _Labels:
    """One sequence of pattern labels: each frame says which pattern it is."""

    def __init__(self, z: np.ndarray) -> None:
        self.z = np.asarray(z, dtype=np.int64)

    def __len__(self) -> int:
        return len(self.z)

    def probs(self, emission: np.ndarray) -> np.ndarray:
        """(T, P): each frame's probability under each phase."""
        return emission[:, self.z].T

    def log_probs(self, log_emission: np.ndarray) -> np.ndarray:
        return log_emission[:, self.z].T

    def add_counts(self, nb: np.ndarray, emission: np.ndarray, weight: np.ndarray) -> None:
        """Add the expected (phase, pattern) counts of the frames, ``weight`` (T, P) each frame's
        phase posterior, to ``nb`` (P, K)."""
        np.add.at(nb.T, self.z, weight)


class _Evidence:
    """One sequence of frames given by their likelihood under every pattern, ``like`` (T, K), each
    row scaled to a maximum of 1 (a frame's constant factor changes no posterior). A phase emits a
    frame from the mixture of its patterns: ``Σ_k emission[p, k] like[t, k]``; labels are the
    case of rows with a single 1."""

    def __init__(self, like: np.ndarray) -> None:
        self.like = like
        self._last: tuple[np.ndarray, np.ndarray] | None = None  # (emission, probs): EM asks twice

    def __len__(self) -> int:
        return len(self.like)

    def probs(self, emission: np.ndarray) -> np.ndarray:
        if self._last is None or self._last[0] is not emission:
            self._last = (emission, self.like @ emission.T)
        return self._last[1]

    def log_probs(self, log_emission: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore"):
            return np.log(self.probs(np.exp(log_emission)))

    def add_counts(self, nb: np.ndarray, emission: np.ndarray, weight: np.ndarray) -> None:
        # each frame's phase weight shared among the patterns by their part in its mixture
        b = self.probs(emission)
        nb += emission * ((weight / np.where(b > 0, b, 1.0)).T @ self.like)


_Observed = _Labels | _Evidence


def _observed(seq: Any) -> _Observed:
    return seq if isinstance(seq, (_Labels, _Evidence)) else _Labels(seq)


def _forward_backward(
    z: Any, emission: np.ndarray, a: np.ndarray, pi: np.ndarray
) -> tuple[float, np.ndarray, np.ndarray]:
    """One sequence ``z`` (labels or :class:`_Evidence`): log-likelihood, state posteriors (T, P)
    and summed pair posteriors (P, P), by the scaled forward–backward recursions."""
    b = _observed(z).probs(emission)  # (T, P) emission probabilities
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


def hmm_log_likelihood(seqs: list[Any], emission: np.ndarray, trans: np.ndarray, start: np.ndarray) -> float:
    """Log-likelihood of the label sequences ``seqs`` under the HMM (forward pass)."""
    return float(sum(_forward_backward(z, emission, trans, start)[0] for z in seqs))


def viterbi(z: Any, emission: np.ndarray, trans: np.ndarray, start: np.ndarray) -> np.ndarray:
    """The most probable state path of one label sequence ``z`` (or :class:`_Evidence`)."""
    with np.errstate(divide="ignore"):  # a cycle's zeros: changes it cannot make
        log_a = np.log(trans)
        log_b = _observed(z).log_probs(np.log(emission))  # (T, P)
    n, p = len(log_b), len(start)
    back = np.zeros((n, p), dtype=np.int64)
    d = np.log(start) + log_b[0]
    for t in range(1, n):
        x = d[:, None] + log_a
        back[t] = np.argmax(x, axis=0)
        d = x[back[t], np.arange(p)] + log_b[t]
    path = np.empty(n, dtype=np.int64)
    path[-1] = int(np.argmax(d))
    for t in range(n - 1, 0, -1):
        path[t - 1] = back[t, path[t]]
    return path


def _allowed(p: int, cycle: bool) -> np.ndarray:
    """(P, P): the phase changes a model may have (off the diagonal): any, or with ``cycle`` only
    to the next phase of a fixed cycle 0 → 1 → … → P−1 → 0."""
    if not cycle or p <= 2:
        return ~np.eye(p, dtype=bool)
    return np.roll(np.eye(p, dtype=bool), 1, axis=1)


def _em(
    seqs: list[_Observed],
    p: int,
    k: int,
    rng: np.random.Generator,
    max_iter: int,
    tol: float,
    cycle: bool = False,
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    emission = rng.dirichlet(np.ones(k), size=p)
    mask = _allowed(p, cycle) | np.eye(p, dtype=bool)
    trans = np.where(mask, 0.05 / np.maximum(mask.sum(axis=1, keepdims=True) - 1, 1), 0.0)
    np.fill_diagonal(trans, 0.95 if p > 1 else 1.0)  # persistent from the start: phases, not frames
    start = np.full(p, 1.0 / p)
    prev = -np.inf
    ll = -np.inf
    for _ in range(max_iter):
        nb = np.zeros((p, k))
        na = np.zeros((p, p))
        n0 = np.zeros(p)
        ll = 0.0
        for z in seqs:
            lz, gamma, xi = _forward_backward(z, emission, trans, start)
            ll += lz
            z.add_counts(nb, emission, gamma)
            na += xi
            n0 += gamma[0]
        emission = (nb + SMOOTHING) / (nb + SMOOTHING).sum(axis=1, keepdims=True)
        trans = np.where(mask, na + SMOOTHING, 0.0)
        trans /= trans.sum(axis=1, keepdims=True)
        start = (n0 + SMOOTHING) / (n0 + SMOOTHING).sum()
        if ll - prev < tol * abs(ll):
            break
        prev = ll
    ll = hmm_log_likelihood(seqs, emission, trans, start)
    return ll, emission, trans, start


def duration_log_pmf(mu: np.ndarray, sd: np.ndarray, d_max: int) -> np.ndarray:
    """(P, d_max): a log-normal (``mu``, ``sd`` of log frames) discretised on 1..d_max frames."""
    d = np.log(np.arange(1, d_max + 1))
    lp = -d[None, :] - 0.5 * ((d[None, :] - mu[:, None]) / sd[:, None]) ** 2
    return lp - _logsumexp(lp, axis=1)[:, None]


def _duration_tables(lp: np.ndarray) -> tuple[np.ndarray, ...]:
    """From the duration log-pmf: the survival ``log P(d' >= d)``, and for a segment cut by the
    start of a recording the residual life ``P(d) = P(d' >= d) / E[d']`` and its survival."""
    with np.errstate(divide="ignore"):
        surv = np.log(np.cumsum(np.exp(lp)[:, ::-1], axis=1)[:, ::-1])
        res = surv - np.log((np.exp(lp) * np.arange(1, lp.shape[1] + 1)).sum(axis=1))[:, None]
        res_surv = np.log(np.cumsum(np.exp(res)[:, ::-1], axis=1)[:, ::-1])
    return surv, res, res_surv


def _ending_at(tables: tuple[np.ndarray, ...], lp: np.ndarray, t: int, n: int) -> np.ndarray:
    """(min(d_max, t), P): duration terms of the segments that end at ``t`` (exclusive) and last
    1, 2, ... frames, in a sequence of ``n`` frames (cut by its start, s = 0, and/or its end)."""
    surv, res, res_surv = tables
    d = min(lp.shape[1], t)
    out = (surv if t == n else lp)[:, :d].T.copy()
    if d == t:  # the longest starts at the sequence's start
        out[-1] = (res_surv if t == n else res)[:, t - 1]
    return out


def _starting_at(tables: tuple[np.ndarray, ...], lp: np.ndarray, s: int, n: int) -> np.ndarray:
    """(min(d_max, n - s), P): duration terms of the segments that start at ``s`` and last 1, 2, ...
    frames (cut by the sequence's start if s = 0, by its end for the one reaching n)."""
    surv, res, res_surv = tables
    d = min(lp.shape[1], n - s)
    out = (res if s == 0 else lp)[:, :d].T.copy()
    if d == n - s:
        out[-1] = (res_surv if s == 0 else surv)[:, d - 1]
    return out


def _hsmm_pass(
    z: Any, log_b: np.ndarray, log_a: np.ndarray, log_start: np.ndarray, lp: np.ndarray, viterbi: bool = False
) -> tuple[float, dict[str, np.ndarray]]:
    """Forward–backward (or, ``viterbi``, max-product) over the segments of one label sequence (or
    :class:`_Evidence`) under an explicit-duration HMM: segments of one phase last d frames (``lp``), the next phase by
    ``log_a`` (no self-transitions), each frame's label by ``log_b``."""
    n, p = len(z), len(log_start)
    d_max = lp.shape[1]
    tables = _duration_tables(lp)
    cum = np.zeros((n + 1, p))
    cum[1:] = np.cumsum(_observed(z).log_probs(log_b), axis=0)
    reduce = (lambda a: np.max(a, axis=0)) if viterbi else (lambda a: _logsumexp(a, axis=0))
    fwd = np.full((n + 1, p), -np.inf)  # a segment of p ends at t (covers ..t-1)
    start = np.full((n + 1, p), -np.inf)  # a segment of p starts at s
    start[0] = log_start
    best_d = np.zeros((n + 1, p), dtype=np.int64)
    best_i = np.zeros((n + 1, p), dtype=np.int64)
    for t in range(1, n + 1):
        s = t - np.arange(1, min(d_max, t) + 1)
        terms = start[s] + _ending_at(tables, lp, t, n) + cum[t] - cum[s]
        fwd[t] = reduce(terms)
        if viterbi:
            best_d[t] = np.argmax(terms, axis=0) + 1
        if t < n:
            x = fwd[t][:, None] + log_a
            start[t] = reduce(x)
            if viterbi:
                best_i[t] = np.argmax(x, axis=0)
    total = float(reduce(fwd[n][:, None]).item()) if viterbi else float(_logsumexp(fwd[n]))
    if viterbi:
        return total, {"fwd": fwd, "best_d": best_d, "best_i": best_i}
    back = np.full((n + 1, p), -np.inf)  # the frames after a segment of p that ends at t
    gen = np.full((n + 1, p), -np.inf)  # the frames from s on, given a segment of p starts at s
    back[n] = 0.0
    for si in range(n - 1, -1, -1):
        ends_at = si + np.arange(1, min(d_max, n - si) + 1)
        gen[si] = _logsumexp(_starting_at(tables, lp, si, n) + cum[ends_at] - cum[si] + back[ends_at], axis=0)
        if si > 0:
            back[si] = _logsumexp(log_a + gen[si][None, :], axis=1)
    with np.errstate(invalid="ignore"):
        starts = np.exp(start[:n] + gen[:n] - total)
        ends = np.exp(fwd[1:] + back[1:] - total)
    occ = np.cumsum(starts, axis=0) - np.r_[np.zeros((1, p)), np.cumsum(ends, axis=0)[:-1]]
    xi = np.zeros((p, p))
    for t in range(1, n):
        xi += np.exp(fwd[t][:, None] + log_a + gen[t][None, :] - total)
    dur = np.zeros((p, d_max))  # segments seen to start and end inside the sequence
    for d in range(1, min(d_max, n - 2) + 1):
        at = np.arange(1, n - d)
        dur[:, d - 1] = np.exp(start[at] + lp[:, d - 1] + cum[at + d] - cum[at] + back[at + d] - total).sum(axis=0)
    return total, {"occ": np.clip(occ, 0.0, None), "first": starts[0], "xi": xi, "dur": dur}


def _log_switches(trans: np.ndarray) -> np.ndarray:
    """Log transition probabilities between segments: none for a single phase (one segment per
    sequence), else ``trans`` (its zero diagonal: a phase never follows itself)."""
    if len(trans) == 1:
        return np.full((1, 1), -np.inf)
    with np.errstate(divide="ignore"):
        return np.log(trans)


def _hsmm_log_likelihood(
    seqs: list[Any], emission: np.ndarray, trans: np.ndarray, start: np.ndarray, lp: np.ndarray
) -> float:
    """Log-likelihood of the label sequences ``seqs`` under the semi-Markov model (forward pass)."""
    log_a, log_b, log_s = _log_switches(trans), np.log(emission), np.log(start)
    return float(sum(_hsmm_pass(z, log_b, log_a, log_s, lp)[0] for z in seqs))


def _hsmm_viterbi(z: Any, emission: np.ndarray, trans: np.ndarray, start: np.ndarray, lp: np.ndarray) -> np.ndarray:
    _, tab = _hsmm_pass(z, np.log(emission), _log_switches(trans), np.log(start), lp, viterbi=True)
    path = np.empty(len(z), dtype=np.int64)
    t, j = len(z), int(np.argmax(tab["fwd"][len(z)]))
    while t > 0:
        d = int(tab["best_d"][t, j])
        path[t - d : t] = j
        t -= d
        if t > 0:
            j = int(tab["best_i"][t, j])
    return path


def _hsmm_em(
    seqs: list[_Observed],
    p: int,
    k: int,
    rng: np.random.Generator,
    max_iter: int,
    tol: float,
    d_max: int,
    mean0: float,
    init: tuple[np.ndarray, ...] | None = None,
    cycle: bool = False,
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """EM of the semi-Markov model from random emissions and durations of mean ``mean0`` frames,
    or from ``init``: (emission, trans, start, (mu, sd) per phase in log frames)."""
    mask = _allowed(p, cycle) if p > 1 else np.ones((1, 1), dtype=bool)
    if init is None:
        emission = rng.dirichlet(np.ones(k), size=p)
        trans = mask.astype(np.float64)
        start = np.full(p, 1.0 / p)
        mu, sd = np.full(p, np.log(mean0)), np.full(p, 0.5)
    else:
        emission, trans, start, dur = (np.array(a, dtype=np.float64) for a in init)
        trans = np.where(mask, trans + SMOOTHING, 0.0)
        mu, sd = dur[:, 0].copy(), dur[:, 1].copy()
    trans /= trans.sum(axis=1, keepdims=True)
    logd = np.log(np.arange(1, d_max + 1))
    prev = ll = -np.inf
    for _ in range(max_iter):
        lp = duration_log_pmf(mu, sd, d_max)
        log_a = _log_switches(trans)
        nb, na, n0, nd = np.zeros((p, k)), np.zeros((p, p)), np.zeros(p), np.zeros((p, d_max))
        ll = 0.0
        for z in seqs:
            lz, st = _hsmm_pass(z, np.log(emission), log_a, np.log(start), lp)
            ll += lz
            z.add_counts(nb, emission, st["occ"])
            na += st["xi"]
            n0 += st["first"]
            nd += st["dur"]
        emission = (nb + SMOOTHING) / (nb + SMOOTHING).sum(axis=1, keepdims=True)
        if p > 1:
            trans = np.where(mask, na + SMOOTHING, 0.0)
            trans /= trans.sum(axis=1, keepdims=True)
        start = (n0 + SMOOTHING) / (n0 + SMOOTHING).sum()
        w = nd.sum(axis=1)
        for j in np.flatnonzero(w > 1e-9):
            mu[j] = (nd[j] * logd).sum() / w[j]
            sd[j] = max(np.sqrt((nd[j] * (logd - mu[j]) ** 2).sum() / w[j]), MIN_LOG_SD)
        if ll - prev < tol * abs(ll):
            break
        prev = ll
    # the likelihood of the parameters returned (the loop's is of the step before)
    ll = _hsmm_log_likelihood(seqs, emission, trans, start, duration_log_pmf(mu, sd, d_max))
    return ll, emission, trans, start, np.c_[mu, sd]


def _run_durations(obs: list[Any], hmm: tuple[Any, ...], d_max: int) -> np.ndarray:
    """(P, 2): log-normal (mu, sd) in log frames of each phase's Viterbi runs under the HMM fit
    ``hmm`` (ll, emission, trans, start), runs cut by a sequence's ends included, each at most
    ``d_max``; a phase without runs gets half of ``d_max``."""
    _, emission, trans, start = hmm
    p = len(start)
    runs: list[list[float]] = [[] for _ in range(p)]
    for z in obs:
        path = viterbi(z, emission, trans, start)
        cut = np.flatnonzero(np.diff(path)) + 1
        for a, b in zip(np.r_[0, cut], np.r_[cut, len(path)]):
            runs[int(path[a])].append(np.log(min(b - a, d_max)))
    out = np.empty((p, 2))
    for j, r in enumerate(runs):
        out[j] = (float(np.mean(r)), max(float(np.std(r)), MIN_LOG_SD)) if r else (np.log(max(d_max / 2, 1.0)), 0.5)
    return out


def _n_params(p: int, k: int, durations: bool = False, cycle: bool = False) -> int:
    changes = int(_allowed(p, cycle).sum(axis=1).max()) if p > 1 else 0  # places a phase may go next
    if durations:  # no self-transitions; a log-normal (2 numbers) per phase
        return (p - 1) + p * max(changes - 1, 0) + p * (k - 1) + 2 * p
    return (p - 1) + p * changes + p * (k - 1)


def recorded_cycles(runs: np.ndarray, p: int) -> np.ndarray:
    """(n, p): the stage durations (frames) of every complete cycle of stages ``0 → 1 → … → p−1``
    among a decoded path's ``runs`` (:attr:`Transitions.runs`: stage, first frame, frames,
    censored; in time order); a cycle with a run cut by a recording's start or end is not
    complete (and no cycle runs across two recordings: their boundary runs are cut)."""
    stage, length, cut = runs[:, 0], runs[:, 2], runs[:, 3].astype(bool)
    out = [
        length[i : i + p]
        for i in np.flatnonzero(stage == 0)
        if i + p <= len(runs) and not cut[i : i + p].any() and np.array_equal(stage[i : i + p], np.arange(p))
    ]
    return np.asarray(out, dtype=np.int64).reshape(-1, p)


def fit_phases(
    labels: Any,
    order: TimeOrder | Any,
    n_phases: int | str = 2,
    *,
    n_patterns: int | None = None,
    seed: int | None = 0,
    restarts: int | None = None,
    max_phases: int = MAX_PHASES,
    max_iter: int = 200,
    tol: float = 1e-7,
    durations: bool = False,
    max_duration: float = MAX_DURATION,
    evidence: Any = None,
    cycle: bool = False,
) -> Phases:
    """The :class:`Phases` of frame ``labels`` (integers ``0..K-1``) in the time ``order`` of their
    frames (a :class:`TimeOrder`, or the frames). ``n_phases``: a positive integer, or ``"auto"``
    (lowest BIC of ``1..max_phases``). EM from ``restarts`` random emissions (``seed``; default
    :data:`RESTARTS`, :data:`EVIDENCE_RESTARTS` with ``evidence``), the best log-likelihood
    kept; the semi-Markov model also from the best HMM's phases. ``durations``: an explicit-duration (semi-Markov) model, each phase's
    duration a log-normal up to ``max_duration`` seconds, instead of the HMM's geometric one (a
    fixed-time signal's phases last about one duration; a geometric one breaks them up); slower,
    O(frames × max_duration / dt) per EM step. ``evidence`` (frames, K): each frame's log-likelihood
    under every pattern (``-inf``, or masked as :meth:`dpgp.DPGP.training_log_likelihoods` gives
    it, where none); the phases are then fitted to what each frame says
    about every pattern, not only to its label (a frame that two patterns explain about equally
    well counts for both), and ``log_likelihood`` is that of the frames' velocities.
    ``cycle``: the phases follow one another in a fixed order, 0 → 1 → … → P−1 → 0 (the stages
    of a fixed-time signal): a phase may only give way to the next, so a brief return to the
    phase before is not a phase of its own; phases keep their order in the cycle, numbered from
    the largest.
    :class:`~dpgp.exceptions.UnorderedFramesError` for frames without times."""
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
    if restarts is None:
        restarts = RESTARTS if evidence is None or durations else EVIDENCE_RESTARTS
    if isinstance(restarts, bool) or not isinstance(restarts, (int, np.integer)) or restarts < 1:
        raise InvalidInputError(f"restarts must be a positive integer, got {restarts!r}")
    labels = labels.astype(np.int64)
    k = int(max(n_patterns or 0, labels.max() + 1))
    seqs_idx = order.sequences()
    seqs = [labels[s] for s in seqs_idx]
    obs: list[_Observed] = [_Labels(z) for z in seqs]
    shift = 0.0
    if evidence is not None:
        ev = np.asarray(np.ma.filled(evidence, -np.inf), dtype=np.float64)  # masked: the pattern cannot have it
        if ev.ndim != 2 or len(ev) != len(labels) or ev.shape[1] < k or np.isnan(ev).any() or np.isposinf(ev).any():
            raise InvalidInputError(
                f"evidence must be a ({len(labels)}, >= {k}) array of log-likelihoods, one row per frame "
                "and one column per pattern (finite, or -inf where a pattern cannot have the frame)"
            )
        top = ev.max(axis=1)
        if not np.isfinite(top).all():
            raise InvalidInputError("evidence: every frame needs a finite log-likelihood under some pattern")
        k = ev.shape[1]
        like = np.exp(ev - top[:, None])
        obs, shift = [_Evidence(like[s]) for s in seqs_idx], float(top.sum())
    if not (isinstance(max_duration, (int, float)) and np.isfinite(max_duration) and max_duration > 0):
        raise InvalidInputError(f"max_duration must be a positive number of seconds, got {max_duration!r}")
    counts = range(1, max_phases + 1) if auto else [int(n_phases)]
    rng = np.random.default_rng(seed)
    d_max = max(1, min(max(len(q) for q in seqs), int(round(max_duration / order.dt))))
    fits: dict[int, tuple[Any, ...]] = {}
    bic: dict[int, float] = {}
    for p in counts:
        runs = int(restarts) if p > 1 else 1
        tries: list[tuple[Any, ...]] = []
        for _ in range(runs):
            if durations:
                tries += [
                    _hsmm_em(obs, p, k, rng, max_iter, tol, d_max, min(m / order.dt, d_max / 2), cycle=cycle)
                    for m in START_DURATIONS
                ]
            else:
                tries.append(_em(obs, p, k, rng, max_iter, tol, cycle))
        if durations and p > 1:  # one more start: the best HMM's phases, their runs as durations
            hmm = max((_em(obs, p, k, rng, max_iter, tol, cycle) for _ in range(HMM_INIT_RESTARTS)), key=lambda r: r[0])
            init = (*hmm[1:], _run_durations(obs, hmm, d_max))
            tries.append(_hsmm_em(obs, p, k, rng, max_iter, tol, d_max, 1.0, init=init, cycle=cycle))
        fits[p] = max(tries, key=lambda r: r[0])
        bic[p] = -2.0 * (fits[p][0] + shift) + _n_params(p, k, durations, cycle) * np.log(len(labels))
    p = min(bic, key=lambda q: bic[q]) if auto else int(n_phases)
    ll, emission, trans, start, *rest = fits[p]
    ll += shift
    dur = rest[0] if durations else None
    path = np.empty(len(labels), dtype=np.int64)
    for s, z in zip(seqs_idx, obs):
        if dur is None:
            path[s] = viterbi(z, emission, trans, start)
        else:
            path[s] = _hsmm_viterbi(z, emission, trans, start, duration_log_pmf(dur[:, 0], dur[:, 1], d_max))
    # number phases by size, largest first (a deterministic name for each); a cycle keeps its order
    sizes = np.bincount(path, minlength=p)
    rank = (np.roll(np.arange(p), -int(np.argmax(sizes))) if cycle else np.argsort(-sizes, kind="stable")).astype(
        np.int64
    )
    new = np.empty(p, dtype=np.int64)
    new[rank] = np.arange(p)
    path = new[path]
    emission, start, trans = emission[rank], start[rank], trans[np.ix_(rank, rank)]
    if dur is not None:  # log-normal of the duration in log seconds
        dur = dur[rank] + np.array([np.log(order.dt), 0.0])
    within = np.zeros((p, k, k), dtype=np.int64)
    has_next = (order.next >= 0) & (path[np.maximum(order.next, 0)] == path)
    np.add.at(within, (path[has_next], labels[has_next], labels[order.next[has_next]]), 1)
    pattern_runs: list[list[tuple[int, int]]] = [[] for _ in range(p)]
    for s in seqs_idx:
        lab, ph = labels[s], path[s]
        cut = np.flatnonzero((np.diff(lab) != 0) | (np.diff(ph) != 0)) + 1
        for a, b in zip(np.r_[0, cut], np.r_[cut, len(s)]):
            pattern_runs[int(ph[a])].append((int(lab[a]), int(b - a)))
    transitions = count_transitions(path, order, p)
    return Phases(
        labels=path,
        emission=emission,
        trans=trans,
        start=start,
        log_likelihood=float(ll),
        bic=bic,
        transitions=transitions,
        within=within,
        pattern_runs=[np.asarray(r, dtype=np.int64).reshape(-1, 2) for r in pattern_runs],
        durations=dur,
        dt=float(order.dt),
        d_max=d_max,
        cycle=bool(cycle and p > 1),
        cycles=recorded_cycles(transitions.runs, p) if cycle and p > 1 else None,
    )


__all__ = ["Phases", "fit_phases", "recorded_cycles", "hmm_log_likelihood", "viterbi", "duration_log_pmf", "MAX_PHASES"]
