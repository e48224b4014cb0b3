"""The paper's empirical distributions of a frame's vehicle count (φ) and positions (ψ), and
their smoothed forms φ̃, ψ̃ that every score uses (issue 36).

A frame's likelihood is ``φ(l) · Π_j ψ(x_j, y_j) · (velocity terms)``; φ and ψ do not depend on
the pattern, so they matter for the total log-likelihood and for generating scenarios.

The paper's φ and ψ are the recorded frequencies: a count or a position bin never seen in
training has probability 0, so one such held-out frame scores -inf and with it a whole
evaluation. Scores therefore use a Dirichlet smoothing of both (:class:`EmpiricalDistributions`
says how), with pseudo-counts set from the training frames by blocked cross-validation
(:meth:`EmpiricalDistributions.from_frames`). Scenarios are still drawn from the recorded φ and
ψ: a generated vehicle stands only where recorded vehicles stood.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .._arrays import as_pairs, check_finite
from .._validate import check_roi, inside_roi
from ..exceptions import DataFormatError, InvalidInputError, ShapeError

_FORMAT_VERSION = 1  # pseudo-counts are optional keys: a reader of version 1 reads the recorded φ, ψ
_MAX_BINS = 10**7  # position bins (80 MB of histogram)
_MAX_SAMPLES = 10**8  # draws per call (0.8-1.6 GB of output)
#: Pseudo-count of :meth:`EmpiricalDistributions.held_out_log_density` for the paper's unsmoothed
#: form (pseudo-counts 0, as model files written before issue 36 hold): Krichevsky–Trofimov's ½,
#: what dpgp scored held-out frames with before the pseudo-counts were set from the data.
HELD_OUT_PSEUDOCOUNT = 0.5
#: Pseudo-counts the cross-validation of :meth:`EmpiricalDistributions.from_frames` chooses
#: among: 10 per decade from 1e-4 to 1e3. The least keeps every score finite (an unseen bin
#: costs about ``log(1e-4 / N)``).
PSEUDOCOUNT_GRID = np.logspace(-4.0, 3.0, 71)
#: Contiguous blocks of frames the cross-validation holds out in turn. In blocks, because
#: consecutive frames share their vehicles: holding out single frames would let a vehicle's
#: neighbours in time vouch for its bin, and would choose too little smoothing for new data.
CV_BLOCKS = 5


class EmpiricalDistributions:
    """φ: the vehicle count per frame; ψ: positions over a grid of bins covering the ROI; and
    their smoothed forms φ̃, ψ̃, which every log density here is.

    The recorded φ is the fraction of training frames with ``l`` vehicles; the recorded ψ a
    histogram of all training positions on ``bins = (nx, ny)`` equal bins over ``roi = (x_min,
    x_max, y_min, y_max)``, uniform inside a bin. Scenarios are drawn from these
    (:meth:`sample_counts`, :meth:`sample_positions`, :meth:`count_pmf`).

    The log densities (:meth:`log_count_pmf`, :meth:`log_position_density`,
    :meth:`log_frame_density`) are a Dirichlet smoothing of them, normalised, with ``N`` frames
    of at most ``L`` vehicles and ``n`` positions recorded:

    - φ̃: ``a_φ = count_pseudocount`` is added to the frames of every count from 1 to ``L``, and
      ``a_φ`` more spread over the larger counts as a geometric tail (``l = L + m`` gets ``a_φ ·
      2^-m``): ``φ̃(l) = (N_l + a_φ) / (N + a_φ (L + 1))``.
    - ψ̃: ``a_ψ = position_pseudocount`` is added to every bin and to one cell more, the plane
      outside the ROI: ``ψ̃ = (n_b + a_ψ) / (n + a_ψ (nx·ny + 1))`` per bin, divided by the
      bin's area. Outside the ROI the cell's mass falls off by e per bin width beyond the
      ROI's edge, ``log ψ̃(x, y) = log(a_ψ / (n + a_ψ (nx·ny + 1))) - log(bin area · (2 nx + 2
      ny + 4)) - d_x / w_x - d_y / w_y`` (``d`` the distance beyond the edge, ``w`` the bin
      width, and ``2 nx + 2 ny + 4`` bin areas the integral of that fall-off): a documented
      finite penalty, never -inf.

    Pseudo-counts of 0 give the paper's unsmoothed φ and ψ (:attr:`is_paper_form`): an unseen
    count, an empty bin or a position outside the ROI then has log density -inf. Model files
    written before issue 36 hold that form; :meth:`held_out_log_density` smooths it by ½ as
    dpgp did then.

    Build one with :meth:`from_frames` (``pseudocount="auto"``: set from the frames by blocked
    cross-validation); store it with :meth:`to_dict` (plain arrays, for a model file) and
    :meth:`from_dict`.
    """

    def __init__(
        self,
        count_hist: Any,
        position_hist: Any,
        roi: Any,
        pseudocount: Any = 0.0,
    ) -> None:
        ch = _floats("count_hist", count_hist)
        ph = _floats("position_hist", position_hist)
        a_count, a_position = _pseudocounts(pseudocount)
        r = np.asarray(check_roi(roi))
        if ch.ndim != 1 or len(ch) < 2:
            raise ShapeError("count_hist must be one-dimensional: frames with 0, 1, 2, ... vehicles")
        if ph.ndim != 2 or 0 in ph.shape or ph.size > _MAX_BINS:
            raise ShapeError(
                f"position_hist must be a non-empty (nx, ny) array of at most {_MAX_BINS} bins, got shape {ph.shape}"
            )
        if np.any(ch < 0) or np.any(ph < 0) or not np.all(np.isfinite(ch)) or not np.all(np.isfinite(ph)):
            raise InvalidInputError("histograms must hold finite counts >= 0")
        with np.errstate(over="ignore"):
            finite = np.isfinite(ch.sum()) and np.isfinite(ph.sum())
        if not finite:
            raise InvalidInputError("the histograms' totals overflow: counts must be frame and vehicle counts")
        if ch[1:].sum() <= 0 or ph.sum() <= 0:
            raise InvalidInputError("the histograms are empty: build them from at least one frame")
        self.count_hist = ch
        self.position_hist = ph
        self.roi = (float(r[0]), float(r[1]), float(r[2]), float(r[3]))
        self.count_pseudocount = a_count
        self.position_pseudocount = a_position
        self._count_p = ch / ch.sum()  # the recorded φ and ψ: what scenarios are drawn from
        self._bin_p = ph / ph.sum()
        self._log_count, self._log_tail = _smoothed_counts(ch, a_count)
        self._log_density, self._log_outside = _smoothed_bins(ph, self.roi, a_position)

    # --- construction --------------------------------------------------------------------------
    @classmethod
    def from_frames(
        cls,
        frames: Any,
        roi: tuple[float, float, float, float] | None = None,
        bins: tuple[int, int] | int = (10, 10),
        pseudocount: Any = "auto",
    ) -> EmpiricalDistributions:
        """φ and ψ of a :class:`dpgp.Frames`.

        ``roi`` defaults to the one ``make_frames`` cropped to (``frames.summary.roi``), else
        to the bounding box of the positions. ``bins`` is ``(nx, ny)`` or one number for both.
        Positions outside ``roi`` raise :class:`InvalidInputError`: ψ must cover every vehicle.
        ``pseudocount``: ``"auto"`` (default) sets φ̃'s and ψ̃'s from the frames: each the value of
        :data:`PSEUDOCOUNT_GRID` that scores best the frames of each of :data:`CV_BLOCKS`
        contiguous blocks held out in turn, under the distributions of the other blocks (with
        fewer than 2 frames, :data:`HELD_OUT_PSEUDOCOUNT`). A number sets both, a pair ``(a_φ,
        a_ψ)`` each; 0 keeps the paper's unsmoothed form.
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
        flat = _flat_bins(roi, (nx, ny), xy)
        position_hist = np.bincount(flat, minlength=nx * ny).astype(np.float64).reshape(nx, ny)
        count_hist = np.bincount(sizes, minlength=2).astype(np.float64)
        if isinstance(pseudocount, str) and pseudocount == "auto":
            pseudocount = _cross_validated(sizes, flat, nx * ny)
        return cls(count_hist, position_hist, roi, pseudocount)

    # --- densities -----------------------------------------------------------------------------
    @property
    def bins(self) -> tuple[int, int]:
        return (int(self.position_hist.shape[0]), int(self.position_hist.shape[1]))

    @property
    def pseudocount(self) -> tuple[float, float]:
        """``(a_φ, a_ψ)``: the pseudo-counts of the smoothed φ̃ and ψ̃."""
        return (self.count_pseudocount, self.position_pseudocount)

    @property
    def is_paper_form(self) -> bool:
        """Whether the densities are the paper's unsmoothed φ and ψ (both pseudo-counts 0, as in
        model files written before issue 36): an unseen count, an empty bin or a position
        outside the ROI then has log density -inf."""
        return self.count_pseudocount == 0.0 and self.position_pseudocount == 0.0

    @property
    def max_count(self) -> int:
        """The largest vehicle count recorded (the largest :meth:`sample_counts` draws)."""
        return int(np.flatnonzero(self._count_p > 0)[-1])

    def count_pmf(self) -> np.ndarray:
        """The recorded φ(l) for l = 0, 1, ..., max_count (what :meth:`sample_counts` draws from)."""
        return self._count_p[: self.max_count + 1].copy()

    def log_count_pmf(self, l: Any) -> np.ndarray | float:
        """log φ̃(l) for a count or an array of counts (whole numbers >= 1: a frame holds at least
        one vehicle); finite for every count unless :attr:`is_paper_form`."""
        arr = np.asarray(l)
        whole = arr.dtype.kind == "f" and np.all(np.isfinite(arr)) and np.all(arr == np.round(arr))
        if arr.dtype.kind not in "iu" and not whole:
            raise InvalidInputError(f"vehicle counts must be whole numbers, got {l!r}")
        if np.any(arr < 1):
            raise InvalidInputError(f"vehicle counts must be at least 1 (a frame holds a vehicle), got {l!r}")
        counts = arr.astype(np.float64)
        largest = len(self._log_count) - 1  # L: the largest count recorded
        seen = counts <= largest
        out = np.empty(counts.shape)
        out[seen] = self._log_count[counts[seen].astype(np.int64)]
        out[~seen] = self._log_tail - (counts[~seen] - largest) * np.log(2.0)  # the geometric tail
        return float(out) if out.ndim == 0 else out

    def log_position_density(self, xy: Any) -> np.ndarray:
        """log ψ̃ at each position of ``xy`` (n, 2), per unit area, inside the ROI and beyond it
        (the class docstring's fall-off); finite unless :attr:`is_paper_form`."""
        pts = as_pairs("xy", xy)
        check_finite("xy", pts)
        inside = inside_roi(pts, self.roi)
        out = np.empty(len(pts))
        ix, iy = _bin_index(self.roi, self.bins, pts[inside])
        out[inside] = self._log_density[ix, iy]
        out[~inside] = self._log_outside - _bin_widths_beyond(self.roi, self.bins, pts[~inside])
        return out

    def log_frame_density(self, xy: Any) -> float:
        """log φ̃(l) + Σ_j log ψ̃(x_j, y_j) for one frame's ``l`` positions ``xy`` (l, 2)."""
        pts = as_pairs("xy", xy)
        return float(self.log_count_pmf(len(pts))) + float(self.log_position_density(pts).sum())

    def log_frame_densities(self, frames: Any) -> np.ndarray:
        """:meth:`log_frame_density` of every frame of a :class:`dpgp.Frames`, at once."""
        per_row = self.log_position_density(frames.xy)
        positions = np.bincount(frames.frame_of_row, weights=per_row, minlength=len(frames))
        return np.asarray(self.log_count_pmf(frames.sizes), dtype=np.float64) + positions

    def for_scoring(self) -> EmpiricalDistributions:
        """These distributions as held-out frames are scored: this object, or for the paper's
        unsmoothed form a copy smoothed by :data:`HELD_OUT_PSEUDOCOUNT` (what dpgp scored such
        frames with before the pseudo-counts were set from the data)."""
        if not self.is_paper_form:
            return self
        return type(self)(self.count_hist, self.position_hist, self.roi, HELD_OUT_PSEUDOCOUNT)

    def held_out_log_density(self, xy: Any) -> float:
        """log φ̃(l) + Σ_j log ψ̃(x_j, y_j) of a frame that was not in training: the smoothed
        densities of :meth:`for_scoring`, so finite for every frame."""
        return self.for_scoring().log_frame_density(xy)

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
            # keys a reader of version 1 ignores: it then reads the recorded φ, ψ (the paper's form)
            "count_pseudocount": np.array(self.count_pseudocount, dtype=np.float64),
            "position_pseudocount": np.array(self.position_pseudocount, dtype=np.float64),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> EmpiricalDistributions:
        """Rebuild from :meth:`to_dict`'s arrays (lists work too, e.g. from JSON). Without the
        pseudo-counts (written before issue 36) the densities are the paper's unsmoothed form
        (:attr:`is_paper_form`), or the one ``pseudocount`` stored then, for both."""
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
        if "count_pseudocount" in d or "position_pseudocount" in d:
            pseudocount: Any = (d.get("count_pseudocount", 0.0), d.get("position_pseudocount", 0.0))
        else:
            pseudocount = d.get("pseudocount", 0.0)
        return cls(d["count_hist"], d["position_hist"], d["roi"], pseudocount)

    def __repr__(self) -> str:
        return (
            f"EmpiricalDistributions({int(self.count_hist.sum())} frames, counts 0-{self.max_count}, "
            f"{self.bins[0]}x{self.bins[1]} bins over roi {self.roi}, "
            + ("the paper's unsmoothed form)" if self.is_paper_form else f"pseudo-counts {self.pseudocount})")
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


def _smoothed_counts(count_hist: np.ndarray, a: float) -> tuple[np.ndarray, float]:
    """log φ̃(l) for l = 0..L (index 0 unused: frames are never empty) and log φ̃ at the first
    count of the tail, ``L + 1`` before its halving (the class docstring's formula)."""
    largest = int(np.flatnonzero(count_hist[1:])[-1]) + 1
    log_total = np.log(count_hist[1 : largest + 1].sum() + a * (largest + 1))
    with np.errstate(divide="ignore"):  # a = 0: the paper's form, -inf for unseen counts
        log_count = np.log(np.r_[0.0, count_hist[1 : largest + 1] + a]) - log_total
        return log_count, float(np.log(a) - log_total)  # logs apart: a tiny a over a large total underflows


def _smoothed_bins(position_hist: np.ndarray, roi: tuple[float, ...], a: float) -> tuple[np.ndarray, float]:
    """log ψ̃ per unit area in each bin, and at the ROI's edge outside it (the class docstring's
    formula). The log area is a sum of logs: a tiny ROI's bin area underflows, its log does not."""
    nx, ny = position_hist.shape
    x0, x1, y0, y1 = roi
    log_area = np.log(x1 - x0) - np.log(nx) + np.log(y1 - y0) - np.log(ny)
    log_total = np.log(position_hist.sum() + a * (nx * ny + 1))
    with np.errstate(divide="ignore"):  # a = 0: the paper's form, -inf for empty bins and outside
        log_density = np.log(position_hist + a) - log_total - log_area
        return log_density, float(np.log(a) - log_total - log_area - np.log(2 * nx + 2 * ny + 4))


#: Most bin widths of fall-off a position beyond the ROI is charged: its log density stays a
#: finite number however far away (and whatever the ROI's width) it lies.
_MAX_FALL_OFF = 1e300


def _bin_widths_beyond(roi: tuple[float, ...], bins: tuple[int, int], xy: np.ndarray) -> np.ndarray:
    """``d_x / w_x + d_y / w_y``: how far beyond the ROI each position lies, in bin widths."""
    x0, x1, y0, y1 = roi
    dx = np.maximum(x0 - xy[:, 0], 0.0) + np.maximum(xy[:, 0] - x1, 0.0)
    dy = np.maximum(y0 - xy[:, 1], 0.0) + np.maximum(xy[:, 1] - y1, 0.0)
    with np.errstate(over="ignore"):
        return np.minimum(dx / (x1 - x0) * bins[0] + dy / (y1 - y0) * bins[1], _MAX_FALL_OFF)


def _cross_validated(sizes: np.ndarray, flat_bins: np.ndarray, n_bins: int) -> tuple[float, float]:
    """``(a_φ, a_ψ)`` by blocked cross-validation (:meth:`EmpiricalDistributions.from_frames`):
    frames' vehicle counts ``sizes`` and their positions' bins ``flat_bins``, frame by frame."""
    if len(sizes) < 2:
        return HELD_OUT_PSEUDOCOUNT, HELD_OUT_PSEUDOCOUNT
    frame_of_row = np.repeat(np.arange(len(sizes)), sizes)
    count_score = np.zeros(len(PSEUDOCOUNT_GRID))
    position_score = np.zeros(len(PSEUDOCOUNT_GRID))
    for block in np.array_split(np.arange(len(sizes)), min(CV_BLOCKS, len(sizes))):
        held = np.zeros(len(sizes), dtype=bool)
        held[block] = True
        count_score += _held_out_counts(sizes[~held], sizes[held])
        rows = held[frame_of_row]
        position_score += _held_out_positions(flat_bins[~rows], flat_bins[rows], n_bins)
    grid = PSEUDOCOUNT_GRID
    return float(grid[np.argmax(count_score)]), float(grid[np.argmax(position_score)])


def _held_out_counts(train: np.ndarray, held: np.ndarray) -> np.ndarray:
    """Σ log φ̃(l) of the held-out counts under φ̃ of the training ones, per grid pseudo-count."""
    a = PSEUDOCOUNT_GRID
    largest = int(train.max())
    n = np.bincount(train, minlength=largest + 1).astype(np.float64)
    values, times = np.unique(held, return_counts=True)
    seen = values <= largest
    score = times[seen] @ np.log(n[values[seen], None] + a)
    score += times[~seen].sum() * np.log(a) - (times[~seen] @ (values[~seen] - largest)) * np.log(2.0)
    return score - len(held) * np.log(len(train) + a * (largest + 1))


def _held_out_positions(train: np.ndarray, held: np.ndarray, n_bins: int) -> np.ndarray:
    """Σ log ψ̃ of the held-out positions' bins under ψ̃ of the training ones (less the bins'
    log area, the same for every pseudo-count), per grid pseudo-count."""
    a = PSEUDOCOUNT_GRID
    n = np.bincount(train, minlength=n_bins).astype(np.float64)
    m = np.bincount(held, minlength=n_bins).astype(np.float64)
    used = np.flatnonzero(m)
    return m[used] @ np.log(n[used, None] + a) - m.sum() * np.log(len(train) + a * (n_bins + 1))


#: Largest pseudo-count taken: its totals over every count and bin stay finite (a fit's never
#: exceeds :data:`PSEUDOCOUNT_GRID`'s 1e3).
MAX_PSEUDOCOUNT = 1e100


def _pseudocounts(value: Any) -> tuple[float, float]:
    """``(a_φ, a_ψ)`` from one number for both or a pair, each in ``[0, MAX_PSEUDOCOUNT]``."""
    arr = _floats("pseudocount", value)
    if arr.shape not in ((), (2,)) or not (np.all(arr >= 0) and np.all(arr <= MAX_PSEUDOCOUNT)):
        raise InvalidInputError(
            f"pseudocount must be a number from 0 to {MAX_PSEUDOCOUNT:g}, or a pair (counts, positions) of them, "
            f"got {value!r:.80}"
        )
    pair = np.broadcast_to(arr, (2,))
    return float(pair[0]), float(pair[1])


def _flat_bins(roi: tuple[float, ...], bins: tuple[int, int], xy: np.ndarray) -> np.ndarray:
    ix, iy = _bin_index(roi, bins, xy)  # type: ignore[arg-type]
    return ix * bins[1] + iy


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


__all__ = ["EmpiricalDistributions", "HELD_OUT_PSEUDOCOUNT", "PSEUDOCOUNT_GRID", "CV_BLOCKS"]
