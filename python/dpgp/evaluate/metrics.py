"""Partition agreement measures used in convergence monitoring."""

from __future__ import annotations

import numpy as np

from ..exceptions import InvalidInputError

#: Labels that are non-negative integers below this are their own group numbers (no sort).
_SMALL_CODES = 4096
#: Items per step of the contingency count: its temporaries stay this small whatever the length
#: (a fit's per-sweep ARI of 10 million labels would otherwise take ~250 MB of int64 copies).
_CHUNK = 1 << 20


def _codes(name: str, labels: object) -> np.ndarray:
    """Group numbers 0.. of a 1-D labeling (integers in [0, :data:`_SMALL_CODES`) as they are, in
    their own dtype, uncopied); any hashable labels (None, mixed types) work."""
    arr = np.asarray(labels, dtype=object) if isinstance(labels, (list, tuple)) else np.asarray(labels)
    if arr.ndim != 1:
        raise InvalidInputError(f"labeling {name} must be one-dimensional, got shape {arr.shape}")
    if arr.dtype.kind in "iu" and len(arr) and 0 <= arr.min() and arr.max() < _SMALL_CODES:
        return arr  # already group numbers (gaps are empty groups): no sort
    try:
        return np.unique(arr, return_inverse=True)[1].reshape(-1)
    except TypeError:  # labels that cannot be ordered: number them by first appearance
        try:
            seen: dict = {}
            return np.array([seen.setdefault(v, len(seen)) for v in arr.tolist()], dtype=np.int64)
        except TypeError as e:
            raise InvalidInputError(f"labeling {name} holds unhashable labels ({e}); use numbers or strings") from None


def adjusted_rand_index(a: object, b: object) -> float:
    """Adjusted Rand index of two labelings of the same items (1 = identical partitions)."""
    a, b = _codes("a", a), _codes("b", b)
    if a.shape != b.shape:
        raise InvalidInputError(f"labelings must be 1-D and of equal length, got {a.shape} and {b.shape}")
    n = len(a)
    if n < 2:
        return 1.0
    if (int(a.max()) + 1) * (int(b.max()) + 1) > 4 * n + _SMALL_CODES**2 // 4:  # sparse numbers: pack them
        a, b = np.unique(a, return_inverse=True)[1], np.unique(b, return_inverse=True)[1]
    na, nb = int(a.max()) + 1, int(b.max()) + 1
    counts = np.zeros(na * nb, dtype=np.int64)
    for s in range(0, n, _CHUNK):
        code = a[s : s + _CHUNK].astype(np.int64) * nb + b[s : s + _CHUNK].astype(np.int64)
        counts += np.bincount(code, minlength=na * nb)
    table = counts.reshape(na, nb)
    # Groups that are empty in one labeling (gaps in its numbers) add no pairs.
    return _ari_of(table, table.sum(axis=1), table.sum(axis=0), n)


def adjusted_rand_index_of_table(rows: object) -> float:
    """:func:`adjusted_rand_index` from the counts of the two labelings' pairs: ``rows`` of
    ``(a, b, count)``, each pair of labels once (a sharded chain's shards count them; the same
    value as from the labels, bitwise)."""
    t = np.asarray(rows, dtype=np.int64).reshape(-1, 3)
    a, b, count = t[:, 0], t[:, 1], t[:, 2]
    n = int(count.sum())
    if n < 2:
        return 1.0
    return _ari_of(count, _grouped_sum(a, count), _grouped_sum(b, count), n)


def _grouped_sum(key: np.ndarray, count: np.ndarray) -> np.ndarray:
    """The sum of ``count`` per distinct ``key`` (exact integers)."""
    codes = np.unique(key, return_inverse=True)[1]
    out = np.zeros(int(codes.max(initial=-1)) + 1, dtype=np.int64)
    np.add.at(out, codes, count)
    return out


def _ari_of(cells: np.ndarray, rows: np.ndarray, cols: np.ndarray, n: int) -> float:
    """The ARI from the contingency counts (any order: the sums are of integers) and the two
    labelings' group sizes."""

    def pairs(x: np.ndarray) -> float:
        return float((x * (x - 1) // 2).sum())

    index, row_pairs, col_pairs = pairs(cells), pairs(rows), pairs(cols)
    expected = row_pairs * col_pairs / (n * (n - 1) / 2)
    maximum = 0.5 * (row_pairs + col_pairs)
    if maximum == expected:
        return 1.0
    return (index - expected) / (maximum - expected)


def canonical_labels(labels: object) -> np.ndarray:
    """Relabel so that groups are numbered in order of first appearance (0, 1, 2, ...)."""
    labels = np.asarray(labels)
    _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first)] = np.arange(len(first))
    return rank[inverse]
