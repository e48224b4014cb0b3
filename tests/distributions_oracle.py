"""φ̃ and ψ̃, the smoothed count and position models (issue 36), and the blocked
cross-validation that sets their pseudo-counts, written out in plain numpy: the oracle of
tests/generate/test_distributions.py and tests/model/test_model.py."""

from __future__ import annotations

import numpy as np

from dpgp.generate.distributions import CV_BLOCKS, PSEUDOCOUNT_GRID


def smoothed_oracle(sizes, xy, roi, bins, a_count, a_position):
    """log φ̃ and log ψ̃ written out in plain numpy, one count and one position at a time."""
    nx, ny = bins
    x0, x1, y0, y1 = roi
    wx, wy = (x1 - x0) / nx, (y1 - y0) / ny
    hist, _, _ = np.histogram2d(xy[:, 0], xy[:, 1], bins=bins, range=((x0, x1), (y0, y1)))
    n_frames, largest = len(sizes), max(sizes)

    def log_phi(l):
        if l <= largest:
            return np.log((np.sum(np.asarray(sizes) == l) + a_count) / (n_frames + a_count * (largest + 1)))
        return np.log(a_count * 0.5 ** (l - largest) / (n_frames + a_count * (largest + 1)))

    def log_psi(x, y):
        total = hist.sum() + a_position * (nx * ny + 1)
        if x0 <= x <= x1 and y0 <= y <= y1:
            i, j = min(int((x - x0) // wx), nx - 1), min(int((y - y0) // wy), ny - 1)
            return np.log((hist[i, j] + a_position) / total / (wx * wy))
        beyond = max(x0 - x, 0, x - x1) / wx + max(y0 - y, 0, y - y1) / wy
        return np.log(a_position / total / (wx * wy * (2 * nx + 2 * ny + 4))) - beyond

    return log_phi, log_psi


def cv_oracle(frames, roi, bins):
    """The blocked cross-validation written out: for every grid pseudo-count, the held-out log
    density of each block's counts and positions under the other blocks' smoothed φ̃ and ψ̃
    (smoothed_oracle); the best pseudo-count of each."""
    blocks = np.array_split(np.arange(len(frames)), CV_BLOCKS)
    scores = np.zeros((len(PSEUDOCOUNT_GRID), 2))
    for g, a in enumerate(PSEUDOCOUNT_GRID):
        for block in blocks:
            rest = frames[np.setdiff1d(np.arange(len(frames)), block)]
            log_phi, log_psi = smoothed_oracle(rest.sizes, rest.xy, roi, bins, a, a)
            held = frames[block]
            scores[g, 0] += sum(log_phi(int(l)) for l in held.sizes)
            scores[g, 1] += sum(log_psi(x, y) for x, y in held.xy)
    return tuple(float(PSEUDOCOUNT_GRID[i]) for i in scores.argmax(axis=0))
