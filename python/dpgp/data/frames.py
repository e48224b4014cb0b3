"""Frames: every vehicle in the region of interest at one instant, for many instants.

:class:`Frames` is a ragged container stored flat (one row per vehicle observation, with frame
offsets), so that the Rust core can borrow all of it without copying.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, overload

import numpy as np

from .._arrays import as_path, as_vector, column_floats, is_path
from .._validate import check_roi, inside_roi
from ..exceptions import DataFormatError, InvalidInputError, ShapeError
from . import _shardfile
from ._previous import HEADING_MIN_SPEED, check_min_speed, previous_columns

if TYPE_CHECKING:
    import pandas as pd


@dataclass(frozen=True)
class Frame:
    """One frame: positions ``xy`` (l, 2) and velocities ``v`` (l, 2) of its ``l`` vehicles, and
    their track ids ``tracks`` (l,), previous velocities ``prev_v`` (l, 2) and previous headings
    ``prev_heading`` (l,) when the frames carry them (else ``None``)."""

    id: object
    xy: np.ndarray
    v: np.ndarray
    tracks: np.ndarray | None = None
    prev_v: np.ndarray | None = None
    prev_heading: np.ndarray | None = None

    @property
    def x(self) -> np.ndarray:
        return self.xy[:, 0]

    @property
    def y(self) -> np.ndarray:
        return self.xy[:, 1]

    @property
    def vx(self) -> np.ndarray:
        return self.v[:, 0]

    @property
    def vy(self) -> np.ndarray:
        return self.v[:, 1]

    def __len__(self) -> int:
        return len(self.xy)


class Frames:
    """A sequence of frames, each a variable number of vehicles with position and velocity.

    Build one with :meth:`from_arrays`, :func:`dpgp.read_frames` or :func:`dpgp.make_frames`.
    ``frames[i]`` is a :class:`Frame`; ``frames[a:b]``, an index array or a boolean mask give a
    new :class:`Frames`. ``labels`` holds per-frame ground-truth pattern labels when known
    (synthetic data), else ``None``. ``tracks`` holds per row the vehicle's track id (int64;
    :func:`dpgp.make_frames` keeps it, so that a vehicle can be followed from frame to frame and
    temporal statistics learned), else ``None`` (frames read without ids). Positions and
    velocities must be finite: a NaN or inf is an :class:`~dpgp.InvalidInputError` naming the
    frame and the vehicle (its row inside the frame), never a frame that scores NaN.

    ``prev_v`` (n, 2) holds per row the vehicle's velocity one grid step earlier, NaN in both
    entries where it has none (its first appearance, after a gap), and ``prev_heading`` (n,)
    the heading it was last travelling in (:meth:`headings`), carried with ``heading_min_speed``
    (m/s); all three are ``None`` for frames without tracks. :func:`dpgp.make_frames` computes
    them from the tracks; they are data only (no fit uses them yet).
    """

    # summary: what dpgp.make_frames left out and why (a dpgp.FramingSummary), else None
    __slots__ = (
        "ids",
        "offsets",
        "xy",
        "v",
        "labels",
        "summary",
        "tracks",
        "prev_v",
        "prev_heading",
        "heading_min_speed",
    )

    def __init__(
        self,
        ids: np.ndarray,
        offsets: np.ndarray,
        xy: np.ndarray,
        v: np.ndarray,
        labels: np.ndarray | None = None,
        tracks: np.ndarray | None = None,
        prev_v: np.ndarray | None = None,
        prev_heading: np.ndarray | None = None,
        heading_min_speed: float | None = None,
    ) -> None:
        # Sizes before any conversion: an array of 1e11 zero-byte items (a damaged model file)
        # would otherwise be converted to 745 GiB of int64 before its length is seen.
        if np.ndim(xy) != 2 or np.shape(xy)[1:] != (2,) or np.shape(v) != np.shape(xy):
            raise ShapeError(f"xy and v must both have shape (n, 2), got {np.shape(xy)} and {np.shape(v)}")
        if np.ndim(offsets) != 1 or np.shape(offsets)[0] != len(ids) + 1 or len(ids) > len(xy):
            raise ShapeError("offsets must run from 0 to the number of rows, one more entry than there are frames")
        for name, a in (("offsets", offsets), ("xy", xy), ("v", v)):
            if isinstance(a, np.ndarray) and (a.dtype.kind not in "biuf" or a.dtype.itemsize == 0):
                raise ShapeError(f"{name} must hold numbers, got dtype {a.dtype}")
        offsets = np.ascontiguousarray(offsets, dtype=np.int64)
        if offsets.ndim != 1 or len(offsets) != len(ids) + 1 or offsets[0] != 0 or offsets[-1] != len(xy):
            raise ShapeError("offsets must run from 0 to the number of rows, one more entry than there are frames")
        if np.any(np.diff(offsets) <= 0):
            raise ShapeError("every frame must hold at least one vehicle")
        if xy.shape != v.shape or xy.ndim != 2 or xy.shape[1] != 2:
            raise ShapeError(f"xy and v must both have shape (n, 2), got {xy.shape} and {v.shape}")
        if labels is not None and np.ndim(labels) != 1:
            raise ShapeError(f"labels must be one label per frame (a 1-D array), got {labels!r:.80}")
        if labels is not None and len(labels) != len(ids):
            raise ShapeError(f"labels has {len(labels)} entries for {len(ids)} frames")
        self.ids = np.asarray(ids)
        self.offsets = offsets
        self.xy = np.ascontiguousarray(xy, dtype=np.float64)
        self.v = np.ascontiguousarray(v, dtype=np.float64)
        _check_finite_rows(self.ids, offsets, self.xy, self.v)
        self.labels = None if labels is None else np.asarray(labels)
        self.tracks = None if tracks is None else _track_ids(tracks, len(self.xy))
        self.prev_v, self.prev_heading, self.heading_min_speed = previous_columns(
            self.ids, offsets, prev_v, prev_heading, heading_min_speed
        )
        self.summary: Any = None  # a dpgp.FramingSummary

    @classmethod
    def from_arrays(
        cls,
        frame: object,
        x: object,
        y: object,
        vx: object,
        vy: object,
        labels: object | None = None,
        track: object | None = None,
        prev_vx: object | None = None,
        prev_vy: object | None = None,
        prev_heading: object | None = None,
        heading_min_speed: float = HEADING_MIN_SPEED,
    ) -> Frames:
        """Group rows by their ``frame`` value (one row per vehicle observation).

        Frames come out in increasing order of ``frame``; rows keep their order inside a frame.
        ``labels``, if given, is one label per *frame* in that order; ``track``, if given, one
        whole-number track id per row. ``prev_vx, prev_vy``, if given, are each row's previous
        velocity (NaN in both where there is none); ``prev_heading`` the heading carried through
        stops (:meth:`headings`), else each previous velocity's own heading, NaN where slower
        than ``heading_min_speed`` (in the rows' own length unit per second: metres give m/s)
        (rows alone hold no history to carry one from).
        """
        frame = np.asarray(frame)
        if frame.ndim != 1:
            raise ShapeError(f"frame must be one-dimensional, got shape {frame.shape}")
        cols = {name: as_vector(name, a) for name, a in (("x", x), ("y", y), ("vx", vx), ("vy", vy))}
        for name, col in cols.items():
            if len(col) != len(frame):
                raise ShapeError(f"{name} has {len(col)} rows but frame has {len(frame)}; they must match")
            bad = ~np.isfinite(col)
            if bad.any():  # named by the caller's row and frame id, before the rows are grouped
                i = int(np.flatnonzero(bad)[0])
                ident = frame[i].item() if isinstance(frame[i], np.generic) else frame[i]
                raise InvalidInputError(
                    f"{name} holds {int(bad.sum())} NaN or infinite value(s), first at row {i} (a vehicle of "
                    f"frame {ident!r}); drop or impute them first"
                )
        if len(frame) == 0:
            raise ShapeError("no rows: a Frames needs at least one vehicle observation")
        if frame.dtype.kind == "f" and np.isnan(frame).any():
            raise InvalidInputError(f"frame has {int(np.isnan(frame).sum())} NaN id(s); every row needs a frame id")
        try:
            order = np.argsort(frame, kind="stable")
        except TypeError as e:  # e.g. None among the ids, or numbers mixed with strings
            raise InvalidInputError(f"frame ids must be numbers or strings that can be sorted ({e})") from None
        sorted_frame = frame[order]
        starts = np.flatnonzero(np.r_[True, sorted_frame[1:] != sorted_frame[:-1]])
        offsets = np.r_[starts, len(frame)]
        xy = np.column_stack([cols["x"][order], cols["y"][order]])
        v = np.column_stack([cols["vx"][order], cols["vy"][order]])
        lab = None if labels is None else np.asarray(labels)
        tracks = None if track is None else _track_ids(track, len(frame))[order]
        if (prev_vx is None) != (prev_vy is None) or (prev_heading is not None and prev_vx is None):
            raise InvalidInputError("give prev_vx and prev_vy together (and prev_heading only with them)")
        prev_v = ph = None
        if prev_vx is not None:
            pv = [_row_column(name, a, len(frame))[order] for name, a in (("prev_vx", prev_vx), ("prev_vy", prev_vy))]
            prev_v = np.column_stack(pv)
            ph = None if prev_heading is None else _row_column("prev_heading", prev_heading, len(frame))[order]
        return cls(sorted_frame[starts], offsets, xy, v, lab, tracks, prev_v, ph, heading_min_speed)

    # --- sequence protocol -------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.ids)

    @overload
    def __getitem__(self, i: int) -> Frame: ...
    @overload
    def __getitem__(self, i: slice | np.ndarray | list) -> Frames: ...
    def __getitem__(self, i):
        if isinstance(i, (int, np.integer)):
            n = len(self)
            if not -n <= i < n:
                raise IndexError(f"frame index {i} out of range for {n} frames")
            i = int(i) % n
            a, b = self.offsets[i], self.offsets[i + 1]
            tr, pv, ph = self._row_columns(slice(a, b))
            return Frame(self.ids[i], self.xy[a:b], self.v[a:b], tr, pv, ph)
        idx = self._selection(i)
        if len(idx) == 0:
            raise ShapeError("selection is empty: a Frames needs at least one frame")
        sizes = self.sizes[idx]
        # the rows of the chosen frames, in selection order, without a loop over frames
        rows = np.arange(int(sizes.sum()), dtype=np.int64)
        rows += np.repeat(self.offsets[idx] - (np.cumsum(sizes) - sizes), sizes)
        tr, pv, ph = self._row_columns(rows)
        out = Frames(
            self.ids[idx],
            np.r_[0, np.cumsum(sizes)],
            self.xy[rows],
            self.v[rows],
            None if self.labels is None else self.labels[idx],
            tr,
            pv,
            ph,
            self.heading_min_speed,
        )
        # A selection keeps how the frames were made (dt, ROI, units) for the model to use.
        out.summary = self.summary
        return out

    def _row_columns(self, rows: Any) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        """The per-row columns beyond positions and velocities (track ids, previous velocities
        and headings), at ``rows``: a selection carries each row's own values."""
        tr, pv, ph = (None if c is None else c[rows] for c in (self.tracks, self.prev_v, self.prev_heading))
        return tr, pv, ph

    def _selection(self, i: object) -> np.ndarray:
        """Frame positions picked by a slice, an integer array or a boolean mask."""
        n = len(self)
        if isinstance(i, slice):
            return np.arange(n)[i]
        arr = np.asarray(i) if isinstance(i, (list, tuple, np.ndarray)) else None
        if arr is not None and arr.size == 0:
            arr = arr.astype(np.int64)
        if arr is None or arr.ndim != 1 or arr.dtype.kind not in "biu":
            raise InvalidInputError(
                f"select frames with an int, a slice, an integer array or a boolean mask, got {i!r:.80}"
            )
        if arr.dtype.kind == "b":
            if len(arr) != n:
                raise ShapeError(f"boolean mask has {len(arr)} entries for {n} frames")
            return np.flatnonzero(arr)
        bad = (arr < -n) | (arr >= n)
        if bad.any():
            raise InvalidInputError(f"frame index {arr[bad][0]} out of range for {n} frames")
        return np.where(arr < 0, arr + n, arr).astype(np.int64)

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self[i]

    def __repr__(self) -> str:
        s = self.sizes
        return f"Frames({len(self)} frames, {self.n_points} vehicles, {s.min()}-{s.max()} per frame)"

    # --- derived views -------------------------------------------------------------------------
    @property
    def sizes(self) -> np.ndarray:
        """Vehicles per frame."""
        return np.diff(self.offsets)

    @property
    def n_points(self) -> int:
        return int(self.offsets[-1])

    @property
    def frame_of_row(self) -> np.ndarray:
        """For every row, the position (0..N-1) of its frame."""
        return np.repeat(np.arange(len(self)), self.sizes)

    def bounds(self) -> tuple[float, float, float, float]:
        """``(x_min, x_max, y_min, y_max)`` of all positions."""
        lo, hi = self.xy.min(axis=0), self.xy.max(axis=0)
        return (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]))

    def crop(self, roi: Any) -> Frames:
        """The vehicles inside ``roi`` ``(x_min, x_max, y_min, y_max)`` (edges included), in
        their frames; frames left empty are dropped, labels, track ids and previous steps kept
        (a vehicle's previous step may lie outside the ROI). The framing summary is not carried
        over (it described the uncropped frames).
        :class:`~dpgp.InvalidInputError` if no vehicle lies inside."""
        box = check_roi(roi)
        keep = inside_roi(self.xy, box)
        if not keep.any():
            raise InvalidInputError(f"no vehicle lies inside the ROI {box} (the frames span {self.bounds()})")
        counts = np.bincount(self.frame_of_row[keep], minlength=len(self))
        kept = counts > 0
        tr, pv, ph = self._row_columns(keep)
        return Frames(
            self.ids[kept],
            np.r_[0, np.cumsum(counts[kept])].astype(np.int64),
            self.xy[keep],
            self.v[keep],
            None if self.labels is None else self.labels[kept],
            tr,
            pv,
            ph,
            self.heading_min_speed,
        )

    def to_pandas(self) -> pd.DataFrame:
        """One row per vehicle observation: ``frame, x, y, vx, vy`` (and ``track``, ``prev_vx``,
        ``prev_vy``, ``prev_heading`` when known)."""
        import pandas as pd

        df = pd.DataFrame(
            {
                "frame": np.repeat(self.ids, self.sizes),
                "x": self.xy[:, 0],
                "y": self.xy[:, 1],
                "vx": self.v[:, 0],
                "vy": self.v[:, 1],
            }
        )
        if self.tracks is not None:
            df["track"] = self.tracks
        if self.prev_v is not None and self.prev_heading is not None:
            df["prev_vx"], df["prev_vy"], df["prev_heading"] = self.prev_v[:, 0], self.prev_v[:, 1], self.prev_heading
        return df

    def headings(self, min_speed: float | None = None) -> np.ndarray:
        """Each vehicle's previous heading, in radians (n,): the direction ``atan2(vy, vx)`` of
        its previous velocity (``prev_v``, one grid step earlier) when that is at least
        ``heading_min_speed`` m/s fast; slower, the heading it had at the frame before, and so
        on back along its track, so that a queued vehicle keeps the heading it had when it last
        moved (a stopped vehicle's velocity direction is noise; its last moving heading is its
        orientation). NaN where the vehicle has no previous step (its first appearance, or the
        first after a gap in its track) or has not moved that fast since it appeared.

        The carried heading needs the vehicle's whole past, which a slice or a shard of frames
        does not hold, so it is computed where the frames are made from tracks and kept as the
        column ``prev_heading``; this returns a copy of it. ``min_speed`` (m/s) may only
        restate the speed the frames were made with (``heading_min_speed``): another needs
        the tracks again (``make_frames(..., heading_min_speed=...)``).
        :class:`~dpgp.InvalidInputError` for frames without previous velocities (frames
        without tracks) or another ``min_speed``.
        """
        if self.prev_heading is None:
            raise InvalidInputError(
                "these frames carry no previous velocities, so no headings: make them from tracks with "
                "dpgp.make_frames (or give prev_vx and prev_vy to Frames.from_arrays)"
            )
        if min_speed is not None and check_min_speed(min_speed) != self.heading_min_speed:
            raise InvalidInputError(
                f"these frames carry headings through stops slower than {self.heading_min_speed:g} m/s, not "
                f"{min_speed!r}: the carried heading needs each track's past, so make the frames again with "
                f"make_frames(..., heading_min_speed={min_speed!r})"
            )
        return self.prev_heading.copy()

    def to_parquet(
        self, directory: str | os.PathLike, shards: int = 1, *, overwrite: bool = False
    ) -> _shardfile.ShardManifest:
        """Write the frames as a directory of ``shards`` Parquet files and a ``manifest.json``
        (:mod:`dpgp.data.shards`), so that a worker can read its own shard alone.

        Shards hold contiguous ranges of the frames in their order (recording order for frames
        from :func:`dpgp.make_frames`), of about equal numbers of vehicles; the manifest keeps
        the framing summary (units, provenance) and the time order. The write is atomic: into a
        temporary directory beside ``directory``, then renamed onto it. An existing non-empty
        directory is a ``FileExistsError`` unless ``overwrite=True`` (which replaces only
        sharded frames). :class:`~dpgp.InvalidInputError` if ``shards`` is not a whole number
        from 1 to the number of frames. Returns the manifest written; read the frames back with
        :func:`dpgp.read_frames`.
        """
        return _shardfile.write_shards(self, directory, shards, overwrite=overwrite)


def _check_finite_rows(ids: np.ndarray, offsets: np.ndarray, xy: np.ndarray, v: np.ndarray) -> None:
    """Refuse a NaN or infinite position or velocity, naming the first frame and vehicle that
    holds one: every score of that frame would be NaN."""
    bad = ~(np.isfinite(xy).all(axis=1) & np.isfinite(v).all(axis=1))
    if not bad.any():
        return
    row = int(np.flatnonzero(bad)[0])
    k = int(np.searchsorted(offsets, row, side="right") - 1)
    what = "position" if not np.isfinite(xy[row]).all() else "velocity"
    value = tuple(float(a) for a in (xy[row] if what == "position" else v[row]))
    ident = ids[k].item() if isinstance(ids[k], np.generic) else ids[k]
    raise InvalidInputError(
        f"frame {k} (id {ident!r}), vehicle {row - int(offsets[k])}: the {what} {value} is not finite; "
        f"{int(bad.sum())} vehicle observation(s) hold NaN or inf in all. Drop or impute them first"
    )


def _row_column(name: str, values: object, n: int) -> np.ndarray:
    """One float per row, NaN allowed (previous velocities and headings)."""
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{name} must hold numbers (NaN where there is none)") from None
    if arr.shape != (n,):
        raise ShapeError(f"{name} must be one value per row ({n}), got shape {arr.shape}")
    return arr


def _track_ids(tracks: object, n: int) -> np.ndarray:
    """Per-row track ids as int64: whole numbers, one per row."""
    arr = np.asarray(tracks)
    if arr.shape != (n,):
        raise ShapeError(f"tracks must be one id per row ({n}), got shape {arr.shape}")
    if arr.dtype.kind == "f" and np.all(np.isfinite(arr)) and np.all(arr == np.round(arr)):
        arr = arr.astype(np.int64)
    if arr.dtype.kind not in "iu":
        raise InvalidInputError(f"track ids must be whole numbers, got dtype {arr.dtype}")
    return np.ascontiguousarray(arr, dtype=np.int64)


# Column names accepted by read_frames, compared case-insensitively, first match wins.
_ALIASES = {
    "frame": ("frame", "frame_idx", "frame_id", "frameid", "frame_index", "time"),
    "x": ("x", "local_x", "pos_x"),
    "y": ("y", "local_y", "pos_y"),
    "vx": ("vx", "vel_x", "v_x", "xvelocity", "velocity_x"),
    "vy": ("vy", "vel_y", "v_y", "yvelocity", "velocity_y"),
}


def _find_columns(columns: list[str], given: dict[str, str | None]) -> dict[str, str]:
    lower = {str(c).strip().lower(): c for c in columns}
    found: dict[str, str] = {}
    for role, aliases in _ALIASES.items():
        name = given.get(role)
        if name is not None:
            if name not in columns:
                raise DataFormatError(f"column {name!r} (given for {role}) is not in the table; it has {list(columns)}")
            found[role] = name
            continue
        match = next((lower[a] for a in aliases if a in lower), None)
        if match is None:
            raise DataFormatError(
                f"no column for {role!r}: expected one of {list(aliases)} (any case), found {list(columns)}; "
                f"name it with read_frames(..., {role}='your_column')"
            )
        found[role] = match
    return found


def _read_table(path: str | os.PathLike) -> pd.DataFrame:
    """A framed table from disk, read by the same sniffing reader as trajectory files."""
    from .tracks import _read_table as read_delimited_or_parquet

    path = as_path(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"no such file: {path}")
    return read_delimited_or_parquet(path, None)


def read_frames(
    source: str | os.PathLike | pd.DataFrame,
    *,
    frame: str | None = None,
    x: str | None = None,
    y: str | None = None,
    vx: str | None = None,
    vy: str | None = None,
) -> Frames:
    """Read an already-framed table (one row per vehicle per frame) into :class:`Frames`.

    ``source`` is a CSV/TSV/whitespace-separated text file, a Parquet file, or a pandas (or
    polars) DataFrame. Columns are found by name — ``frame``/``frame_idx``/``frame_id``,
    ``x``, ``y``, ``vx``/``vel_x``, ``vy``/``vel_y`` in any case — or named explicitly.

    ``source`` may also be a directory of sharded frames (:meth:`Frames.to_parquet`): the
    frames written, with their ids, labels, track ids and framing summary
    (:class:`~dpgp.DataFormatError` naming the file if a shard or the manifest is missing or
    damaged).
    """
    import pandas as pd

    if _shardfile.is_sharded(source):
        if any(name is not None for name in (frame, x, y, vx, vy)):
            raise InvalidInputError("column names apply to a table, not to a directory of sharded frames")
        return from_stored(_shardfile.read_all(source))
    if is_path(source):
        df = _read_table(source)
    elif hasattr(source, "to_pandas") and not isinstance(source, pd.DataFrame):
        df = source.to_pandas()  # polars
    elif isinstance(source, pd.DataFrame):
        df = source
    else:
        raise DataFormatError(f"read_frames takes a path or a DataFrame, got {type(source).__name__}")
    cols = _find_columns(list(df.columns), {"frame": frame, "x": x, "y": y, "vx": vx, "vy": vy})
    values = {}
    for role in ("x", "y", "vx", "vy"):
        try:
            col = column_floats(pd.to_numeric(df[cols[role]], errors="coerce"), cols[role])
        except OverflowError:  # pandas meets an integer past the float range
            col = column_floats(df[cols[role]], cols[role])
        bad = ~np.isfinite(col)
        if bad.any():
            raise DataFormatError(
                f"column {cols[role]!r} has {int(bad.sum())} missing or non-numeric value(s), "
                f"first at row {int(np.flatnonzero(bad)[0])}"
            )
        values[role] = col
    return Frames.from_arrays(df[cols["frame"]].to_numpy(), values["x"], values["y"], values["vx"], values["vy"])


def from_stored(parts: _shardfile.StoredFrames) -> Frames:
    """:class:`Frames` from the arrays read from shards (:mod:`dpgp.data.shards`)."""
    out = Frames(
        parts.ids,
        parts.offsets,
        parts.xy,
        parts.v,
        parts.labels,
        parts.tracks,
        parts.prev_v,
        parts.prev_heading,
        parts.heading_min_speed,
    )
    out.summary = parts.summary
    return out


def as_frames(frames: Any) -> Frames:
    """``frames`` as :class:`Frames`: a ``Frames`` as it is, a framed DataFrame or a directory of
    frame shards (:meth:`Frames.to_parquet`) read by :func:`read_frames`;
    :class:`~dpgp.ShapeError` for anything else."""
    if isinstance(frames, Frames):
        return frames
    if hasattr(frames, "columns"):
        return read_frames(frames)
    if isinstance(frames, (str, os.PathLike)):
        if os.path.isdir(frames):
            return read_frames(frames)
        raise ShapeError(
            f"{os.fspath(frames)!r} is not a directory of frame shards; read a file first with "
            "dpgp.read_frames(path) (or dpgp.read(path) for tracks)"
        )
    raise ShapeError(f"expected dpgp.Frames, a framed DataFrame or a directory of shards, got {type(frames).__name__}")


__all__ = ["Frame", "Frames", "read_frames", "as_frames"]
