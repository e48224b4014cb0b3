"""Pattern transitions and dwell times of any fit (issue 20).

Counts which pattern follows which between consecutive frames (:mod:`dpgp.data.timeorder`), how
unbroken recordings enter and leave, and how long each pattern lasts: a *run* is a maximal stretch
of consecutive frames with one pattern; its dwell is its number of frames times ``dt``. A run cut by
the start or end of a recording (or by a gap) is *censored*: the pattern may have lasted longer."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..data.timeorder import TimeOrder, time_order
from ..exceptions import InvalidInputError, ModelFileError


@dataclass(frozen=True, eq=False)
class Transitions:
    """Transition counts between consecutive frames' patterns, scene entries and exits, and runs.

    ``counts[i, j]``: consecutive frame pairs with pattern ``i`` then ``j``; ``entry[k]``: unbroken
    recordings that start in pattern ``k``; ``exit[k]``: those that end in it; ``runs``: one row per
    run, ``(pattern, first frame index, n_frames, censored)``; ``dt``: the grid step (s)."""

    counts: np.ndarray
    entry: np.ndarray
    exit: np.ndarray
    runs: np.ndarray
    dt: float

    @property
    def n_patterns(self) -> int:
        return len(self.entry)

    @property
    def probs(self) -> np.ndarray:
        """``probs[i, j]``: probability that a frame of pattern ``i`` is followed by one of ``j``;
        with :attr:`exit_probs` each row sums to 1 (0 for a pattern never seen before a frame)."""
        return self.counts / np.maximum(self._row_totals(), 1)[:, None]

    @property
    def exit_probs(self) -> np.ndarray:
        """Probability that a recording ends after a frame of each pattern."""
        return self.exit / np.maximum(self._row_totals(), 1)

    @property
    def entry_probs(self) -> np.ndarray:
        """Probability of each pattern at the start of an unbroken recording."""
        return self.entry / max(int(self.entry.sum()), 1)

    def _row_totals(self) -> np.ndarray:
        return self.counts.sum(axis=1) + self.exit

    @property
    def share_same(self) -> float:
        """Share of consecutive frame pairs that keep their pattern (NaN with no pairs)."""
        total = int(self.counts.sum())
        return float(np.trace(self.counts) / total) if total else float("nan")

    def dwell(self, k: int | None = None, censored: bool = True) -> np.ndarray:
        """Dwell times (s) of pattern ``k``'s runs (every pattern's with ``None``); ``censored=False``
        keeps only the runs seen to start and end inside a recording."""
        keep = np.ones(len(self.runs), dtype=bool) if censored else self.runs[:, 3] == 0
        if k is not None:
            keep &= self.runs[:, 0] == k
        return self.runs[keep, 2] * self.dt

    def mean_dwell(self) -> np.ndarray:
        """Mean dwell (s) per pattern over all its runs (NaN for a pattern without runs)."""
        out = np.full(self.n_patterns, np.nan)
        for k in range(self.n_patterns):
            d = self.dwell(k)
            if len(d):
                out[k] = d.mean()
        return out

    def summary(self) -> str:
        """Text for ``dpgp info``: pairs, share kept, runs (mean, median, longest), top transitions."""
        d = self.dwell()
        if not len(d):
            return "transitions: no frames"
        lines = [
            f"transitions: {int(self.counts.sum())} consecutive frame pairs (dt {self.dt:g} s), "
            f"{int(self.entry.sum())} unbroken recording(s)",
            f"  consecutive frames share a pattern {100 * self.share_same:.1f}% of the time",
            f"  runs: {len(d)}, mean {d.mean():.2f} s, median {np.median(d):.2f} s, longest {d.max():.2f} s",
        ]
        off = self.counts.copy()
        np.fill_diagonal(off, 0)
        top = np.argsort(off, axis=None)[::-1][:5]
        moves = [f"{i}->{j} ({off[i, j]})" for i, j in zip(*np.unravel_index(top, off.shape)) if off[i, j] > 0]
        if moves:
            lines.append("  most frequent changes: " + ", ".join(moves))
        md = self.mean_dwell()
        big = np.argsort(-np.bincount(self.runs[:, 0], weights=self.runs[:, 2], minlength=self.n_patterns))[:5]
        lines.append("  mean dwell of the largest patterns: " + ", ".join(f"{k}: {md[k]:.2f} s" for k in big))
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """Plain values (what a model file stores)."""
        return {
            "counts": self.counts.tolist(),
            "entry": self.entry.tolist(),
            "exit": self.exit.tolist(),
            "runs": self.runs.tolist(),
            "dt": self.dt,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], n_patterns: int | None = None) -> Transitions:
        """The inverse of :meth:`to_dict`; :class:`~dpgp.ModelFileError` if inconsistent."""
        try:
            counts = np.asarray(d["counts"], dtype=np.int64).reshape(len(d["entry"]), len(d["entry"]))
            entry, exit_ = np.asarray(d["entry"], dtype=np.int64), np.asarray(d["exit"], dtype=np.int64)
            runs = np.asarray(d["runs"], dtype=np.int64).reshape(-1, 4)
            dt = float(d["dt"])
        except (KeyError, TypeError, ValueError) as e:
            raise ModelFileError(f"the stored transitions are inconsistent ({e})") from None
        k = len(entry)
        if (
            exit_.shape != (k,)
            or (n_patterns is not None and k != n_patterns)
            or min(counts.min(initial=0), entry.min(initial=0), exit_.min(initial=0), runs.min(initial=0)) < 0
            or (len(runs) and runs[:, 0].max() >= k)
            or not (np.isfinite(dt) and dt > 0)
        ):
            raise ModelFileError("the stored transitions do not fit the model's patterns")
        return cls(counts, entry, exit_, runs, dt)


def count_transitions(
    labels: Any, order: TimeOrder | Any, n_patterns: int | None = None, dt: float | None = None
) -> Transitions:
    """The :class:`Transitions` of frame ``labels`` (integers ``0..K-1``) in the time ``order`` of
    their frames (a :class:`TimeOrder`, or the frames / their ids, whose order is then taken with
    ``dt``). :class:`~dpgp.exceptions.UnorderedFramesError` if the frames have no times."""
    if not isinstance(order, TimeOrder):
        order = time_order(order, dt)
    labels = np.asarray(labels)
    if labels.shape != (len(order),) or (len(labels) and (labels.dtype.kind not in "iu" or labels.min() < 0)):
        raise InvalidInputError(f"labels must be {len(order)} non-negative integers, one per frame")
    labels = labels.astype(np.int64)
    k = int(max(n_patterns or 0, labels.max() + 1 if len(labels) else 0))
    counts = np.zeros((k, k), dtype=np.int64)
    has_next = order.next >= 0
    np.add.at(counts, (labels[has_next], labels[order.next[has_next]]), 1)
    entry = np.bincount(labels[order.prev < 0], minlength=k)
    exit_ = np.bincount(labels[order.next < 0], minlength=k)
    runs = []
    for seq in order.sequences():
        lab = labels[seq]
        cut = np.flatnonzero(np.diff(lab)) + 1
        starts, ends = np.r_[0, cut], np.r_[cut, len(lab)]
        for a, b in zip(starts, ends):
            runs.append((lab[a], seq[a], b - a, int(a == 0 or b == len(lab))))
    return Transitions(counts, entry, exit_, np.asarray(runs, dtype=np.int64).reshape(-1, 4), order.dt)


__all__ = ["Transitions", "count_transitions"]
