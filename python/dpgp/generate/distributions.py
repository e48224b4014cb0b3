"""The paper's empirical distributions of a frame's vehicle count (φ) and positions (ψ).

A frame's likelihood is ``φ(l) · Π_j ψ(x_j, y_j) · (velocity terms)``; φ and ψ do not depend on
the pattern, so they matter for the total log-likelihood and for generating scenarios.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .._arrays import as_pairs, check_finite
from .._validate import check_roi, inside_roi
from ..exceptions import DataFormatError, InvalidInputError, ShapeError

_FORMAT_VERSION = 1
_MAX_BINS = 10**7  # position bins (80 MB of histogram)
_MAX_SAMPLES = 10**8  # draws per call (0.8-1.6 GB of output)
#: Pseudocount of :meth:`EmpiricalDistributions.held_out_log_density` (Krichevsky–Trofimov's ½).
HELD_OUT_PSEUDOCOUNT = 0.5


class EmpiricalDistributions:
    """φ: the vehicle count per frame; ψ: positions over a grid of bins covering the ROI.

    ``φ(l)`` is the fraction of training frames with ``l`` vehicles. ``ψ`` is a histogram of all
    training positions on ``bins = (nx, ny)`` equal bins over ``roi = (x_min, x_max, y_min,
    y_max)``, uniform inside a bin, so it is a density (per unit area). ``pseudocount`` is
    added to every count from 1 to the largest seen and to every position bin; with the
    default 0 an unseen count or an empty bin has probability 0 (log -inf). Positions outside
    the ROI always have density 0.

    Build one with :meth:`from_frames`; store it with :meth:`to_dict` (plain arrays, for a model
    file) and :meth:`from_dict`.
    """

    def __init__(
        self,
        count_hist: Any,
        position_hist: Any,
        roi: Any,
        pseudocount: float = 0.0,
    ) -> None:
        ch = _floats("count_hist", count_hist)
        ph = _floats("position_hist", position_hist)
        pc = _floats("pseudocount", pseudocount)
        if pc.ndim != 0:
            raise InvalidInputError(f"pseudocount must be one number >= 0, got {pseudocount!r}")
        r = np.asarray(check_roi(roi))
        if ch.ndim != 1 or len(ch) < 2:
            raise ShapeError("count_hist must be one-dimensional: frames with 0, 1, 2, ... vehicles")
        if ph.ndim != 2 or 0 in ph.shape or ph.size > _MAX_BINS:
            raise ShapeError(
                f"position_hist must be a non-empty (nx, ny) array of at most {_MAX_BINS} bins, got shape {ph.shape}"
            )
        if not (np.isfinite(pc) and pc >= 0):
            raise InvalidInputError(f"pseudocount must be >= 0, got {pseudocount!r}")
        if np.any(ch < 0) or np.any(ph < 0) or not np.all(np.isfinite(ch)) or not np.all(np.isfinite(ph)):
            raise InvalidInputError("histograms must hold finite counts >= 0")
        self.count_hist = ch
        self.position_hist = ph
        self.roi = (float(r[0]), float(r[1]), float(r[2]), float(r[3]))
        self.pseudocount = float(pc)
        counts = ch.copy()
        counts[1:] += self.pseudocount  # never frames with 0 vehicles: make_frames drops them
        pos = ph + self.pseudocount
        with np.errstate(over="ignore"):
            finite = np.isfinite(counts.sum()) and np.isfinite(pos.sum())
        if not finite:
            raise InvalidInputError("the histograms' totals overflow: counts must be frame and vehicle counts")
        if counts[1:].sum() <= 0 or pos.sum() <= 0:
            raise InvalidInputError("the histograms are empty: build them from at least one frame")
        self._count_p = counts / counts.sum()
        area = (r[1] - r[0]) / ph.shape[0] * (r[3] - r[2]) / ph.shape[1]
        self._bin_p = pos / pos.sum()
        with np.errstate(divide="ignore"):
            self._log_count = np.log(self._count_p)
            self._log_density = np.log(self._bin_p) - np.log(area)

    # --- construction --------------------------------------------------------------------------
    @classmethod
    def from_frames(
        cls,
        frames: Any,
        roi: tuple[float, float, float, float] | None = None,
        bins: tuple[int, int] | int = (10, 10),
        pseudocount: float = 0.0,
    ) -> EmpiricalDistributions:
        """φ and ψ of a :class:`dpgp.Frames`.

        ``roi`` defaults to the one ``make_frames`` cropped to (``frames.summary.roi``), else
        to the bounding box of the positions. ``bins`` is ``(nx, ny)`` or one number for both.
        Positions outside ``roi`` raise :class:`InvalidInputError`: ψ must cover every vehicle.
        """
        nx, ny = _bins(bins)
        xy = np.asarray(frames.xy, dtype=np.float64)
        sizes = np.asarray(frames.sizes)
        if len(sizes) == 0:
            raise ShapeError("no frames: φ and ψ need at least one")
        if roi is None:
            summary = getattr(frames, "summary", None)
            roi = getattr(summary, "roi", None)
        if roi is None:
            lo, hi = xy.min(axis=0), xy.max(axis=0)
            pad = np.where(hi > lo, 0.0, 0.5)  # all positions on one line: give the box a width
            roi = (lo[0] - pad[0], hi[0] + pad[0], lo[1] - pad[1], hi[1] + pad[1])
        roi = check_roi(roi)
        outside = ~inside_roi(xy, roi)
        if outside.any():
            i = int(np.flatnonzero(outside)[0])
            raise InvalidInputError(
                f"{int(outside.sum())} position(s) lie outside the roi {roi}, first {tuple(xy[i])}; "
                "crop the frames to it (make_frames(..., roi=...)) or give a roi that covers them"
            )
        ix, iy = _bin_index(roi, (nx, ny), xy)
        position_hist = np.zeros((nx, ny))
        np.add.at(position_hist, (ix, iy), 1.0)
        count_hist = np.bincount(sizes, minlength=2).astype(np.float64)
        return cls(count_hist, position_hist, roi, pseudocount)

    # --- densities -----------------------------------------------------------------------------
    @property
    def bins(self) -> tuple[int, int]:
        return (int(self.position_hist.shape[0]), int(self.position_hist.shape[1]))

    @property
    def max_count(self) -> int:
        """The largest vehicle count with a nonzero probability."""
        return int(np.flatnonzero(self._count_p > 0)[-1])

    def count_pmf(self) -> np.ndarray:
        """φ(l) for l = 0, 1, ..., max_count."""
        return self._count_p[: self.max_count + 1].copy()

    def log_count_pmf(self, l: Any) -> np.ndarray | float:
        """log φ(l), -inf for a count never seen; ``l`` a number or an array of counts."""
        arr = np.asarray(l)
        if arr.dtype.kind not in "iu" and not (arr.dtype.kind == "f" and np.all(arr == np.round(arr))):
            raise InvalidInputError(f"vehicle counts must be whole numbers, got {l!r}")
        a = arr.astype(np.int64)
        ok = (a >= 0) & (a < len(self._log_count))
        out = np.full(a.shape, -np.inf)
        out[ok] = self._log_count[a[ok]]
        return float(out) if out.ndim == 0 else out

    def log_position_density(self, xy: Any) -> np.ndarray:
        """log ψ at each position of ``xy`` (n, 2), per unit area; -inf outside the ROI."""
        pts = as_pairs("xy", xy)
        check_finite("xy", pts)
        out = np.full(len(pts), -np.inf)
        inside = inside_roi(pts, self.roi)
        ix, iy = _bin_index(self.roi, self.bins, pts[inside])
        out[inside] = self._log_density[ix, iy]
        return out

    def log_frame_density(self, xy: Any) -> float:
        """log φ(l) + Σ_j log ψ(x_j, y_j) for one frame's ``l`` positions ``xy`` (l, 2)."""
        pts = as_pairs("xy", xy)
        return float(self.log_count_pmf(len(pts))) + float(self.log_position_density(pts).sum())

    def held_out_log_density(self, xy: Any) -> float:
        """log φ̃(l) + Σ_j log ψ̃(x_j, y_j): φ and ψ smoothed for scoring frames that were not in
        training, where a count or a bin never seen would otherwise give -inf.

        Half a frame (:data:`HELD_OUT_PSEUDOCOUNT`) is added to every count from 1 to the largest
        seen ``L``, and another half spread over the larger counts as a geometric tail
        (``l = L + m`` gets ``½ · 2^-m``); half a vehicle is added to every position bin. Both stay
        normalised; positions outside the ROI still have density 0 (-inf). The generator and
        :meth:`log_frame_density` keep the unsmoothed φ and ψ.
        """
        pts = as_pairs("xy", xy)
        check_finite("xy", pts)
        c = HELD_OUT_PSEUDOCOUNT
        seen = self.count_hist[1:]
        largest = len(seen)
        total = seen.sum() + c * largest + c  # counts 1..L smoothed, plus the tail's mass c
        l = len(pts)
        if l == 0:
            log_count = -np.inf  # make_frames never gives an empty frame
        elif l <= largest:
            log_count = float(np.log((seen[l - 1] + c) / total))
        else:
            log_count = float(np.log(c / total) - (l - largest) * np.log(2.0))
        nx, ny = self.bins
        x0, x1, y0, y1 = self.roi
        area = (x1 - x0) / nx * (y1 - y0) / ny
        log_bin = np.log((self.position_hist + c) / (self.position_hist.sum() + c * nx * ny)) - np.log(area)
        inside = inside_roi(pts, self.roi)
        if not inside.all():
            return -np.inf
        ix, iy = _bin_index(self.roi, self.bins, pts)
        return log_count + float(log_bin[ix, iy].sum())

    # --- sampling ------------------------------------------------------------------------------
    def sample_counts(self, n: int, rng: Any = None) -> np.ndarray:
        """``n`` vehicle counts drawn from φ (int64)."""
        gen = _rng(rng)
        return gen.choice(len(self._count_p), size=_count("n", n), p=self._count_p).astype(np.int64)

    def sample_positions(self, n: int, rng: Any = None) -> np.ndarray:
        """``n`` positions (n, 2) drawn from ψ: a bin by its probability, then uniformly inside it."""
        gen = _rng(rng)
        n = _count("n", n)
        nx, ny = self.bins
        flat = gen.choice(nx * ny, size=n, p=self._bin_p.ravel())
        ix, iy = np.divmod(flat, ny)
        u = gen.random((n, 2))
        x0, x1, y0, y1 = self.roi
        wx, wy = (x1 - x0) / nx, (y1 - y0) / ny
        return np.column_stack([x0 + (ix + u[:, 0]) * wx, y0 + (iy + u[:, 1]) * wy])

    # --- storage -------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, np.ndarray]:
        """Plain numpy arrays (for an ``.npz`` model file; no pickle). Inverse of :meth:`from_dict`."""
        return {
            "version": np.array(_FORMAT_VERSION, dtype=np.int64),
            "count_hist": self.count_hist.copy(),
            "position_hist": self.position_hist.copy(),
            "roi": np.array(self.roi, dtype=np.float64),
            "pseudocount": np.array(self.pseudocount, dtype=np.float64),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> EmpiricalDistributions:
        """Rebuild from :meth:`to_dict`'s arrays (lists work too, e.g. from JSON)."""
        missing = [k for k in ("count_hist", "position_hist", "roi") if k not in d]
        if missing:
            raise DataFormatError(f"not a stored EmpiricalDistributions: missing {missing}")
        version = d.get("version", _FORMAT_VERSION)
        try:
            version = int(np.asarray(version))
        except (TypeError, ValueError, OverflowError):
            raise DataFormatError(
                f"EmpiricalDistributions format version must be a whole number, got {version!r:.40}"
            ) from None
        if version > _FORMAT_VERSION:
            raise DataFormatError(
                f"EmpiricalDistributions format {version} is newer than this dpgp reads ({_FORMAT_VERSION})"
            )
        return cls(d["count_hist"], d["position_hist"], d["roi"], d.get("pseudocount", 0.0))

    def __repr__(self) -> str:
        return (
            f"EmpiricalDistributions({int(self.count_hist.sum())} frames, counts 0-{self.max_count}, "
            f"{self.bins[0]}x{self.bins[1]} bins over roi {self.roi})"
        )


#: A position less than this share of a bin below an edge counts as on it (in the upper bin).
#: Recorded positions often lie exactly on edges (positions on a decimal grid, an ROI from the
#: data's own extremes), and then the rounding of ``(x - x0) / width`` alone would pick their
#: bin, differently after an offset or a change of units. That rounding is about
#: ``1e-16 |x| / width``: for NGSIM's state-plane feet (6e6 ft) and 1-ft bins, 1e-9 of a bin.
_EDGE_TOLERANCE = 1e-6


def _bin_index(
    roi: tuple[float, float, float, float], bins: tuple[int, int], xy: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    x0, x1, y0, y1 = roi
    nx, ny = bins
    # the upper edge belongs to the last bin, as in numpy.histogram
    ix = np.minimum(((xy[:, 0] - x0) / (x1 - x0) * nx + _EDGE_TOLERANCE).astype(np.int64), nx - 1)
    iy = np.minimum(((xy[:, 1] - y0) / (y1 - y0) * ny + _EDGE_TOLERANCE).astype(np.int64), ny - 1)
    return ix, iy


def _bins(bins: Any) -> tuple[int, int]:
    arr = np.atleast_1d(np.asarray(bins))
    if arr.shape == (1,):
        arr = np.r_[arr, arr]
    if arr.shape != (2,) or arr.dtype.kind not in "iu" or np.any(arr < 1) or int(arr[0]) * int(arr[1]) > _MAX_BINS:
        raise InvalidInputError(
            f"bins must be a positive whole number or a pair (nx, ny) of at most {_MAX_BINS} bins in all, got {bins!r}"
        )
    return int(arr[0]), int(arr[1])


def _count(name: str, n: Any) -> int:
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or not 0 <= n <= _MAX_SAMPLES:
        raise InvalidInputError(f"{name} must be a whole number from 0 to {_MAX_SAMPLES}, got {n!r}")
    return int(n)


def _rng(rng: Any) -> np.random.Generator:
    try:
        return np.random.default_rng(rng)
    except (TypeError, ValueError) as e:
        raise InvalidInputError(f"rng must be None, a seed >= 0 or a numpy Generator, got {rng!r} ({e})") from None


def _floats(name: str, value: Any) -> np.ndarray:
    try:
        arr = np.asarray(value)
        if arr.dtype.kind not in "biuf":
            raise TypeError(f"dtype {arr.dtype}")
        return arr.astype(np.float64)
    except (TypeError, ValueError) as e:
        raise InvalidInputError(f"{name} must hold real numbers, got {value!r:.80} ({e})") from None


__all__ = ["EmpiricalDistributions"]
