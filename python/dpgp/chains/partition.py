"""Summaries of a posterior over partitions, from label draws shaped ``(draws, items)``.

- :func:`similarity`: the posterior co-clustering (similarity) matrix, computed block by block
  of rows, never one N×N array per draw.
- :func:`expected_loss`: the posterior expected Binder or VI loss of a partition, from the
  contingency tables of the partition with every draw (O(draws·N), no N×N matrix at all).
- :func:`salso`: the partition that minimises that expected loss, searched as SALSO does
  (Dahl, Johnson & Müller 2022, "Search algorithms and loss functions for Bayesian clustering",
  JCGS): random sequential allocations, then sweetening scans that move one item at a time to
  its best cluster, and zealous updates that dissolve a cluster and reallocate its items.
- :func:`credible_ball`: the credible ball of Wade & Ghahramani (2018) around a point estimate.

Losses, for partitions c, c' of N items with cluster sizes n_k, m_j and contingency n_kj:
``"binder"`` is the share of the N(N-1)/2 pairs on which c and c' disagree (together in one,
apart in the other; equal costs; 1 - Rand index) = (Σn_k² + Σm_j² - 2Σn_kj²) / (N(N-1));
``"vi"`` is the variation of information in bits,
(Σ n_k log2 n_k + Σ m_j log2 m_j - 2 Σ n_kj log2 n_kj) / N.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..exceptions import InvalidInputError, ShapeError

LOSSES = ("binder", "vi")


def _check_loss(loss: str) -> str:
    if loss not in LOSSES:
        raise InvalidInputError(f"loss must be one of {LOSSES}, got {loss!r}")
    return loss


def compact(labels: Any) -> np.ndarray:
    """Labels renumbered 0..K-1 along the last axis, per row (any hashable-free integer labels)."""
    a = np.asarray(labels)
    if a.ndim == 1:
        return np.unique(a, return_inverse=True)[1].reshape(a.shape).astype(np.int64)
    return np.stack([compact(row) for row in a]) if len(a) else a.astype(np.int64)


def as_draws(draws: object) -> np.ndarray:
    """Draws as a compact int64 (draws, items) array; a typed error for anything else."""
    a = np.asarray(draws)
    if a.ndim != 2 or a.shape[0] == 0 or a.shape[1] == 0:
        raise ShapeError(f"label draws must be a non-empty (draws, items) array, got shape {a.shape}")
    if a.dtype.kind not in "iu":
        if a.dtype.kind == "f" and np.all(np.isfinite(a)) and np.all(a == np.round(a)):
            a = a.astype(np.int64)
        else:
            raise InvalidInputError(f"labels must be integers, got dtype {a.dtype}")
    return compact(a)


def _as_partition(labels: object, n: int) -> np.ndarray:
    c = np.asarray(labels)
    if c.shape != (n,):
        raise ShapeError(f"a partition of the {n} items needs {n} labels, got shape {c.shape}")
    if c.dtype.kind not in "iu":
        raise InvalidInputError(f"labels must be integers, got dtype {c.dtype}")
    return compact(c)


# --- similarity ------------------------------------------------------------------------------
def similarity(draws: object, rows: object = None, block: int = 512, dtype: type = np.float32) -> np.ndarray:
    """Posterior similarity: the share of draws in which items i and j share a cluster.

    ``rows`` (indices) gives only those rows, shape (len(rows), N); by default the full (N, N)
    matrix. Work is done ``block`` rows at a time with a small integer counter, so the memory
    beyond the result is O(block·N) whatever the number of draws (the full float32 matrix of
    10,000 items takes 400 MB).
    """
    d = as_draws(draws)
    s, n = d.shape
    if s >= 2**31:
        raise InvalidInputError("too many draws")
    counter = np.uint16 if s < 2**16 else np.uint32
    full = rows is None
    idx = np.arange(n) if full else np.asarray(rows, dtype=np.int64).ravel()
    if idx.size and (idx.min() < -n or idx.max() >= n):
        raise InvalidInputError(f"rows must index the {n} items")
    out: np.ndarray = np.empty((len(idx), n), dtype=dtype)
    for start in range(0, len(idx), block):
        r = idx[start : start + block]
        # With the full matrix only the columns from this block on are new; the rest is the
        # transpose of rows already done.
        lo = start if full else 0
        acc = np.zeros((len(r), n - lo), dtype=counter)
        hit = np.empty((len(r), n - lo), dtype=bool)
        for t in range(s):
            np.equal(d[t, r][:, None], d[t, lo:][None, :], out=hit)
            acc += hit
        out[start : start + len(r), lo:] = acc
        out[start : start + len(r), lo:] /= s
        if full:
            out[start + len(r) :, start : start + len(r)] = out[start : start + len(r), start + len(r) :].T
    return out


# --- expected loss ---------------------------------------------------------------------------
def _xlog2x(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(x > 0, x * np.log2(np.where(x > 0, x, 1.0)), 0.0)


def losses(labels: object, draws: object, loss: str = "vi") -> np.ndarray:
    """The loss between the partition ``labels`` and each draw: shape (draws,)."""
    _check_loss(loss)
    d = as_draws(draws)
    s, n = d.shape
    c = _as_partition(labels, n)
    k, j = int(c.max()) + 1, int(d.max()) + 1
    h = _xlog2x if loss == "vi" else np.square

    def per_draw(index: np.ndarray, size: int) -> np.ndarray:
        """Σ h(count) over the cells of each draw's table (only the non-empty cells)."""
        counts = np.bincount(index.ravel(), minlength=s * size)
        cell = np.flatnonzero(counts)
        return np.bincount(cell // size, weights=h(counts[cell].astype(float)), minlength=s)

    rows = np.arange(s)[:, None]
    own = float(h(np.bincount(c).astype(float)).sum())  # Σ h(n_k), the same for every draw
    theirs = per_draw(rows * j + d, j)  # Σ h(m_j) per draw
    joint = per_draw((rows * k + c[None, :]) * j + d, k * j)  # Σ h(n_kj) per draw
    total = own + theirs - 2.0 * joint
    return total / max(n * (n - 1), 1) if loss == "binder" else total / n


def expected_loss(labels: object, draws: object, loss: str = "vi") -> float:
    """Posterior expected Binder or VI loss of the partition ``labels`` (the mean over draws)."""
    return float(losses(labels, draws, loss).mean())


# --- SALSO search ----------------------------------------------------------------------------
class _Search:
    """Greedy moves of one item against all draws at once.

    ``t[s·J + j, k]`` counts the items in draw s's cluster j and candidate cluster k. Up to a
    constant shared by every choice, putting item i into cluster k changes the expected loss by
    ``g(n_k) - 2·mean_s g(t[s, d_si, k])`` (counts without i; a new cluster scores g(0) = 0),
    with g(x) = x for Binder and g(x) = f(x+1) - f(x), f(x) = x log2 x, for VI. ``gt`` keeps
    g(t) so that a move costs one gather of (draws, K) values: O(draws·K) per item.
    """

    def __init__(self, d: np.ndarray, loss: str, max_clusters: int, rng: np.random.Generator) -> None:
        self.rng = rng
        self.s, self.n = d.shape
        j = int(d.max()) + 1
        self.u = (np.arange(self.s)[None, :] * j + d.T).copy()  # (N, draws) rows of t per item
        x = np.arange(self.n + 2, dtype=float)
        self.g = x.copy() if loss == "binder" else _xlog2x(x + 1) - _xlog2x(x)
        self.max_clusters = max_clusters
        self.cap = min(max_clusters, 16)
        self.t = np.zeros((self.s * j, self.cap), dtype=np.int32)
        self.gt = np.zeros((self.s * j, self.cap))
        self.size = np.zeros(self.cap, dtype=np.int64)
        self.c = np.full(self.n, -1, dtype=np.int64)

    def _grow(self) -> None:
        cap = min(self.cap * 2, self.max_clusters)
        pad = ((0, 0), (0, cap - self.cap))
        self.t, self.gt = np.pad(self.t, pad), np.pad(self.gt, pad)
        self.size = np.pad(self.size, (0, cap - self.cap))
        self.cap = cap

    def _delta(self, i: int, k: int) -> float:
        """Change of the expected loss (times a constant) from adding i to k as it stands."""
        return float(self.g[self.size[k]] - 2.0 * self.gt[self.u[i], k].mean())

    def _update(self, i: int, k: int, step: int) -> None:
        rows = self.u[i]
        self.t[rows, k] += step
        self.gt[rows, k] = self.g[self.t[rows, k]]
        self.size[k] += step

    def remove(self, i: int) -> float:
        k = int(self.c[i])
        if k < 0:
            return 0.0
        self._update(i, k, -1)
        self.c[i] = -1
        return -self._delta(i, k)

    def add(self, i: int, k: int) -> float:
        while k >= self.cap:
            self._grow()
        delta = self._delta(i, k)
        self._update(i, k, +1)
        self.c[i] = k
        return delta

    def _scores(self, i: int) -> tuple[np.ndarray, int]:
        """Loss change of putting i into each slot (inf where empty) and the slot a new
        cluster would take (scoring 0), with i not in any cluster."""
        used = self.size > 0
        empty = np.flatnonzero(~used)
        new = int(empty[0]) if len(empty) else self.cap
        if used.sum() >= self.max_clusters:
            new = -1  # no room for another cluster
        if not used.any():
            return np.full(self.cap, np.inf), new
        delta = self.g[self.size] - 2.0 * self.gt[self.u[i]].mean(axis=0)
        delta[~used] = np.inf
        return delta, new

    def best(self, i: int) -> int:
        """The cluster (existing, or a new one) that minimises the loss; exact ties are broken
        at random, so that runs leave plateaus (e.g. every pair together in half the draws) on
        different sides."""
        delta, new = self._scores(i)
        lowest = min(float(delta.min()), 0.0 if new >= 0 else np.inf)
        ties = np.flatnonzero(delta <= lowest + 1e-12)
        if new >= 0 and lowest >= -1e-12:
            ties = np.r_[ties, new]
        return int(ties[0]) if len(ties) == 1 else int(self.rng.choice(ties))

    def place(self, i: int) -> bool:
        """Move item i to its best cluster if that strictly lowers the loss; whether it moved."""
        old = int(self.c[i])
        self.remove(i)
        delta, new = self._scores(i)
        stay = 0.0 if self.size[old] == 0 else delta[old]  # alone: staying is a new cluster
        k = int(np.argmin(delta))
        if new >= 0 and delta[k] > 0.0:
            k, best = new, 0.0
        else:
            best = float(delta[k])
        if best < stay - 1e-12:
            self.add(i, k)
            return True
        self.add(i, old)
        return False


def _labels(c: np.ndarray) -> np.ndarray:
    return compact(c)


def salso(
    draws: object,
    loss: str = "vi",
    n_runs: int = 8,
    max_scans: int = 20,
    max_zealous: int | None = None,
    max_clusters: int | None = None,
    init: object = None,
    seed: int = 0,
) -> PointEstimate:
    """The partition minimising the posterior expected ``loss`` over the draws, SALSO-style.

    ``n_runs`` random sequential allocations are each improved by sweetening scans (until no item
    moves, at most ``max_scans``) and zealous updates (each cluster in turn dissolved and its
    items reallocated in random order, kept if the loss falls; at most ``max_zealous`` per run,
    default all clusters); ``init`` adds starting partitions (e.g. the chains' last draws).
    The best by exact expected loss wins. Deterministic given ``seed``.
    """
    _check_loss(loss)
    d = as_draws(draws)
    s, n = d.shape
    if not (isinstance(n_runs, (int, np.integer)) and n_runs >= 0):
        raise InvalidInputError(f"n_runs must be a non-negative integer, got {n_runs!r}")
    starts = [] if init is None else [_as_partition(c, n) for c in np.atleast_2d(np.asarray(init))]
    if n_runs == 0 and not starts:
        raise InvalidInputError("nothing to search from: n_runs=0 and no init partitions")
    cap = n if max_clusters is None else int(max_clusters)
    if cap < 1:
        raise InvalidInputError(f"max_clusters must be positive, got {max_clusters}")
    rng = np.random.default_rng(seed)
    best: tuple[float, np.ndarray] | None = None
    for run in range(n_runs + len(starts)):
        search = _Search(d, loss, cap, rng)
        if run < len(starts):
            start = starts[run]
            if start.max() >= cap:
                continue
            for i in range(n):
                search.add(i, int(start[i]))
        else:
            for i in rng.permutation(n):  # sequential allocation
                search.add(int(i), search.best(int(i)))
        for _ in range(max_scans):  # sweetening
            if not any([search.place(int(i)) for i in rng.permutation(n)]):
                break
        _zealous(search, rng, max_zealous)
        c = _labels(search.c)
        value = expected_loss(c, d, loss)
        if best is None or value < best[0] - 1e-12:
            best = (value, c)
    assert best is not None
    return PointEstimate(_by_size(best[1]), loss, best[0])


def _zealous(search: _Search, rng: np.random.Generator, limit: int | None) -> None:
    """Dissolve each cluster in turn and reallocate its items greedily in random order; keep
    the result if the expected loss fell (tracked exactly by the moves' deltas)."""
    clusters = [int(k) for k in rng.permutation(np.flatnonzero(search.size > 0))]
    for k in clusters[: limit if limit is not None else len(clusters)]:
        members = np.flatnonzero(search.c == k)
        if len(members) < 2:
            continue
        change = sum(search.remove(int(i)) for i in members)
        for i in rng.permutation(members):
            change += search.add(int(i), search.best(int(i)))
        if change >= -1e-9:  # no better: put the cluster back together
            for i in members:
                search.remove(int(i))
            for i in members:
                search.add(int(i), k)


def _by_size(c: np.ndarray) -> np.ndarray:
    """Clusters numbered by decreasing size, ties by first item (the order DPGP uses)."""
    sizes = np.bincount(c)
    first = np.full(len(sizes), len(c))
    np.minimum.at(first, c, np.arange(len(c)))
    order = np.lexsort((first, -sizes))
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return rank[c]


@dataclass(frozen=True)
class PointEstimate:
    """A summary partition: ``labels`` (clusters by decreasing size), the ``loss`` it minimises
    and its posterior ``expected_loss``."""

    labels: np.ndarray
    loss: str
    expected_loss: float

    @property
    def n_clusters(self) -> int:
        return int(self.labels.max()) + 1 if len(self.labels) else 0

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        return self.labels if dtype is None else self.labels.astype(dtype)

    def __len__(self) -> int:
        return len(self.labels)


# --- credible ball ---------------------------------------------------------------------------
@dataclass(frozen=True)
class CredibleBall:
    """Wade & Ghahramani's (2018) credible ball: the smallest ball around the point estimate,
    in the given loss as a distance, that holds ``level`` of the draws. Its bounds, each a
    draw inside the ball: ``horizontal`` the farthest from the estimate; ``upper_vertical``
    the farthest among those with the fewest clusters; ``lower_vertical`` the farthest among
    those with the most."""

    radius: float
    level: float
    loss: str
    horizontal: np.ndarray
    upper_vertical: np.ndarray
    lower_vertical: np.ndarray


def credible_ball(estimate: object, draws: object, loss: str = "vi", level: float = 0.95) -> CredibleBall:
    _check_loss(loss)
    if not 0.0 < level <= 1.0:
        raise InvalidInputError(f"level must lie in (0, 1], got {level}")
    d = as_draws(draws)
    dist = losses(np.asarray(estimate), d, loss)
    radius = float(np.sort(dist)[int(np.ceil(level * len(dist))) - 1])
    inside = np.flatnonzero(dist <= radius + 1e-12)
    k = d[inside].max(axis=1) + 1

    def farthest(candidates: np.ndarray) -> np.ndarray:
        return _by_size(d[candidates[np.argmax(dist[candidates])]])

    return CredibleBall(
        radius, level, loss, farthest(inside), farthest(inside[k == k.min()]), farthest(inside[k == k.max()])
    )


__all__ = ["similarity", "losses", "expected_loss", "salso", "credible_ball", "PointEstimate", "CredibleBall", "LOSSES"]
