"""Partition agreement measures used in convergence monitoring."""

from __future__ import annotations

import numpy as np

from ..exceptions import InvalidInputError


def _codes(name: str, labels: object) -> np.ndarray:
    """Group numbers 0.. of a 1-D labeling; any hashable labels (None, mixed types) work."""
    arr = np.asarray(labels, dtype=object) if isinstance(labels, (list, tuple)) else np.asarray(labels)
    if arr.ndim != 1:
        raise InvalidInputError(f"labeling {name} must be one-dimensional, got shape {arr.shape}")
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
    table = np.zeros((a.max() + 1, b.max() + 1), dtype=np.int64)
    np.add.at(table, (a, b), 1)

    def pairs(x: np.ndarray) -> float:
        return float((x * (x - 1) // 2).sum())

    index, rows, cols = pairs(table), pairs(table.sum(axis=1)), pairs(table.sum(axis=0))
    expected = rows * cols / (n * (n - 1) / 2)
    maximum = 0.5 * (rows + cols)
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
