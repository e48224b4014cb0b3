"""Framing a track file too large for memory straight into frame shards (issue 33), in time
windows: :func:`frame_to_shards`, public in :mod:`dpgp.data.shards`.

The result equals ``make_frames(read_tracks(path, ...), ...).to_parquet(out, shards)`` frame for
frame (ids, points, velocities, track ids, the framing summary, the shard cuts), but no step
holds more than a window of the tracks and a shard of the frames. The file is read four times
over, the first from the source and the others from scratch files inside the temporary
directory of the write:

1. **Scan** the source in chunks of rows (Parquet row groups, CSV chunks, SUMO timesteps): each
   row's id, time, position (and velocity, NGSIM's duplicate check, size columns) is kept, and
   put into a *bucket* by its time window, ``floor(t / window)`` (scene by scene when the file
   has scenes). Only the distinct track ids, a few numbers and one chunk stay in memory, so the
   file need not be sorted by time. Track numbers are given as ``read_tracks`` gives them (in
   the sorted order of the ids) once every id has been seen.
2. **Check** the buckets in time order, carrying per track only its last sample: time repeats
   or goes backwards inside a track (as ``read_tracks`` refuses them), NGSIM's duplicate rows,
   clashing rows and trips (``read_ngsim``).
3. **Typical step** (only when ``max_gap`` is not given): the median of the same steps between
   consecutive samples that ``make_frames`` samples, found by their positions in the track-sorted
   table, which the counts of pass 2 give.
4. **Frame** each window with the framing code of :func:`dpgp.make_frames`, over the rows of the
   buckets within a margin on both sides; a grid point is kept by the window its time falls in.
   The margin, ``(w + 4) * max_gap + dt`` (``w`` the smoothing window, or 3), holds every sample
   the point's interpolation, differences and smoothing look at, and enough more that a track
   cut at the margin looks the same near the point as the whole track: each point comes out
   exactly as from the whole table. The summary's counts of segments and gaps are made as the
   buckets go by, carrying each track's open segment. Each track's last grid point (its
   velocity and carried heading, inside the ROI or not) is carried too, so that the next
   window's previous steps are the whole table's (:mod:`._previous`). Frames go to a scratch
   file in order.

Then the shards are cut as :meth:`Frames.to_parquet` cuts them (about equal numbers of
vehicles, from the frames' sizes) and written one at a time from the scratch file, with the
manifest, and the temporary directory is renamed onto the target: a failure leaves nothing.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import tempfile
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from .._arrays import column_floats, is_path
from .._constants import DEFAULT_DT
from ..exceptions import DataFormatError, InvalidInputError
from . import _shardfile as sf
from ._previous import HEADING_MIN_SPEED, PerTrack, check_min_speed
from .framing import _GRID_EPS, _MAX_GRID_NUMBER, _check_options, _positive, _resample
from .provenance import FramingSummary, describe_tracks
from .tracks import (
    _PRESET_ALIASES,
    _PRESETS,
    NGSIM_FRAME_SECONDS,
    _check_positive,
    _check_unique_columns,
    _damaged_file_errors,
    _existing,
    _first_line,
    _is_number,
    _name_ngsim_columns,
    _numeric,
    _read_sumo_csv,
    _resolve_columns,
    is_sumo_xml,
    sumo_velocity,
    sumo_xml_chunks,
)

if TYPE_CHECKING:
    import pandas as pd

_NGSIM_SPLIT_GAP = 1.0  # read_ngsim's default split_gap, which read_tracks(preset="ngsim") uses
_TYPICAL_SAMPLE = 1_000_000  # make_frames' typical step looks at up to this many steps
_SIZE_COLUMNS = (("v_length", "v_Width"), ("length", "width"))


def frame_to_shards(
    source: str | os.PathLike,
    out: str | os.PathLike,
    shards: int = 1,
    *,
    preset: str | None = None,
    id: str | int | list[str | int] | None = None,
    t: str | int | None = None,
    x: str | int | None = None,
    y: str | int | None = None,
    vx: str | int | None = None,
    vy: str | int | None = None,
    scene: str | int | None = None,
    time_scale: float | None = None,
    sort: bool = False,
    roi: tuple[float, float, float, float] | None = None,
    dt: float = DEFAULT_DT,
    velocity: str = "auto",
    smoothing: tuple[int, int] | None = None,
    units: str | float | None = None,
    max_gap: float | None = None,
    window: float = 600.0,
    overwrite: bool = False,
    chunk_rows: int = 1 << 20,
    heading_min_speed: float = HEADING_MIN_SPEED,
) -> sf.ShardManifest:
    """Frame a track file that need not fit in memory straight into a directory of frame shards.

    The same frames, shards and manifest as
    ``dpgp.make_frames(dpgp.read_tracks(source, id=..., ..., preset=preset, sort=sort), roi,
    dt, velocity, smoothing, units, max_gap=max_gap, out=out, shards=shards)``, but read and
    framed ``window`` seconds of recording at a time, so that memory holds one window of tracks
    (with a margin) and one shard of frames, never the whole file. Read them back with
    :func:`dpgp.read_frames` or shard by shard (:func:`read_shard`).

    This is a function of its own rather than a path given to :func:`dpgp.make_frames`:
    ``make_frames`` takes a table and returns the frames in memory, which is what a file too
    large for memory cannot give; this one returns only the manifest written. (It also reads
    the file, which ``make_frames``, below the readers, does not.)

    Parameters
    ----------
    source
        A track file as :func:`dpgp.read_tracks` reads it: CSV (any separator, ``.gz`` too) or
        Parquet, or SUMO FCD (``.xml``, ``.xml.gz``, or the CSV of ``xml2csv``); with
        ``preset="ngsim"`` a raw NGSIM file as :func:`dpgp.read_ngsim` reads it. The rows may
        come in any order (with ``sort=True``; else, as ``read_tracks`` requires, in time order
        inside each track).
    out, shards, overwrite
        As for :meth:`Frames.to_parquet`: the directory, the number of shards, and whether
        existing sharded frames there may be replaced. The target is checked before any work.
    preset, id, t, x, y, vx, vy, scene, time_scale, sort
        How to read the file: as for :func:`dpgp.read_tracks` (``preset="ngsim"``: as
        :func:`dpgp.read_ngsim`, with its ``split_gap`` of 1 s).
    roi, dt, velocity, smoothing, units, max_gap, heading_min_speed
        How to frame the tracks: as for :func:`dpgp.make_frames` (each track's last grid point is
        carried from window to window, so previous velocities and headings match too).
    window
        Seconds of recording framed at a time (and the time span of the scratch buckets the
        file is sorted into). Memory goes with the rows in a window plus its margins of
        ``(w + 4) * max_gap + dt`` on each side (``w``: the smoothing window, else 3).
    chunk_rows
        Rows read from the source at a time.

    Returns
    -------
    ShardManifest
        The manifest written (:func:`read_manifest`), with the framing summary.

    Notes
    -----
    ``make_frames``' limit of 200 million vehicle-times on the grid does not apply. NGSIM rows
    count as the same (and one is dropped) when all their values are equal as read, column by
    column, in the chunk each comes in: numbers as numbers, text as text.
    """
    path = _source_path(source)
    n_shards = sf.check_shards(shards)
    target = sf.check_target(out, overwrite)
    opts = _Options.check(roi, dt, velocity, smoothing, units, max_gap, window, chunk_rows, heading_min_speed)
    reader = _Reader.open(path, preset, dict(id=id, t=t, x=x, y=y, vx=vx, vy=vy, scene=scene), time_scale, sort)
    sf._pyarrow()
    tmp = tempfile.mkdtemp(prefix=sf.temp_prefix(target), suffix=".tmp", dir=os.path.dirname(target))
    try:
        work = os.path.join(tmp, ".work")
        os.mkdir(work)
        doc = _run(reader, opts, n_shards, tmp, work)
        shutil.rmtree(work)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return sf.commit(tmp, target, doc)


def _source_path(source: Any) -> str:
    if not is_path(source):
        raise InvalidInputError(
            f"frame_to_shards reads a track file, got {type(source).__name__}; for a table already in memory use "
            "dpgp.make_frames(tracks, ..., out=directory, shards=n)"
        )
    return _existing(source)


class _Options(NamedTuple):
    roi: tuple[float, float, float, float] | None
    dt: float
    velocity: str
    smoothing: tuple[int, int] | None
    units: Any
    scale: float
    units_name: str | None
    max_gap: float | None
    window: float
    chunk_rows: int
    heading_min_speed: float = HEADING_MIN_SPEED

    @classmethod
    def check(
        cls,
        roi: Any,
        dt: Any,
        velocity: Any,
        smoothing: Any,
        units: Any,
        max_gap: Any,
        window: Any,
        chunk_rows: Any,
        heading_min_speed: Any = HEADING_MIN_SPEED,
    ) -> _Options:
        roi, dt, smoothing, scale, units_name, max_gap = _check_options(roi, dt, velocity, smoothing, units, max_gap)
        window = _positive("window", window, "seconds of recording framed at a time")
        if isinstance(chunk_rows, (bool, np.bool_)) or not isinstance(chunk_rows, (int, np.integer)) or chunk_rows < 1:
            raise InvalidInputError(f"chunk_rows must be a whole number of rows (1 or more), got {chunk_rows!r}")
        min_speed = check_min_speed(heading_min_speed)
        return cls(roi, dt, velocity, smoothing, units, scale, units_name, max_gap, window, int(chunk_rows), min_speed)


# ---------------------------------------------------------------------------------------------
# reading the source in chunks, each normalised to the columns framing needs
# ---------------------------------------------------------------------------------------------


class _Reader:
    """A track file read in chunks as ``read_tracks`` (or ``read_ngsim``) would read it whole."""

    def __init__(self, path: str, kind: str, fmt: str, units: str | None, given: dict[str, Any], **kw: Any) -> None:
        self.path, self.kind, self.fmt, self.units, self.given = path, kind, fmt, units, given
        self.preset: str | None = kw.get("preset")
        self.spec: dict[str, Any] = kw.get("spec", {})
        self.time_scale: float | None = kw.get("time_scale")
        self.sort: bool = bool(kw.get("sort", False))
        self.cols: dict[str, Any] | None = None  # roles -> columns, from the first chunk (NGSIM: {})
        self.scale = 1.0
        self.sizes: tuple[str, str] | None = None
        self.sizes_ok = True  # False once a chunk's size columns are not numbers

    @classmethod
    def open(cls, path: str, preset: Any, given: dict[str, Any], time_scale: Any, sort: Any) -> _Reader:
        if not isinstance(sort, (bool, np.bool_)):
            raise InvalidInputError(f"sort must be True or False, got {sort!r}")
        if preset is not None:
            preset = _PRESET_ALIASES.get(str(preset).lower(), str(preset).lower())
            if preset == "ngsim":
                if any(v is not None for v in given.values()) or time_scale is not None or sort:
                    raise InvalidInputError(
                        "preset='ngsim' reads NGSIM's own columns (read_ngsim): column names, time_scale and "
                        "sort do not apply"
                    )
                return cls(path, "ngsim", "ngsim", "ft", given)
            if preset not in _PRESETS:
                raise InvalidInputError(f"unknown preset {preset!r}; choose one of {sorted(_PRESETS) + ['ngsim']}")
        if preset is None and path.lower().endswith((".xml", ".xml.gz")):
            preset = "sumo"
        spec = dict(_PRESETS.get(preset or "", {}))
        return cls(
            path, "table", preset or "table", spec.get("units"), given,
            preset=preset, spec=spec, time_scale=time_scale, sort=bool(sort),
        )  # fmt: skip

    # -- raw chunks --------------------------------------------------------------------------

    def raw_chunks(self, rows: int) -> Iterator[pd.DataFrame]:
        path = self.path
        if self.kind == "ngsim":
            yield from self._ngsim_chunks(rows)
            return
        if self.preset == "sumo":
            if is_sumo_xml(path):
                for df in sumo_xml_chunks(path, rows):
                    yield sumo_velocity(df)
            else:
                for df in self._table_chunks(rows, None):
                    yield sumo_velocity(_read_sumo_csv(df, path))
            return
        names = self.spec.get("names")
        for df in self._table_chunks(rows, names):
            if names and list(df.columns) == list(range(len(names))):
                df = df.set_axis(names, axis=1)
            yield df

    def _table_chunks(self, rows: int, names: list[str] | None) -> Iterator[pd.DataFrame]:
        """A delimited text or Parquet file in chunks, read as ``tracks._read_table`` reads it."""
        import pandas as pd

        path = self.path
        if path.lower().endswith((".parquet", ".pq")):
            import pyarrow.parquet as pq

            try:
                pf = pq.ParquetFile(path)
                for batch in pf.iter_batches(batch_size=rows):
                    yield batch.to_pandas()
            except Exception as e:  # noqa: BLE001 - pyarrow raises its own types for a file that is not Parquet
                raise DataFormatError(f"{path} is not a readable Parquet file: {e}") from None
            return
        first = _first_line(path)
        if "\x00" in first:
            raise DataFormatError(f"{path} is a binary file, not a text table (Parquet files must end in .parquet)")
        sep = next((s for s in ("\t", ";", ",") if s in first), r"\s+")
        tokens = [tok.strip().strip('"') for tok in re.split(sep, first.strip())]
        header = None if names is not None or all(_is_number(tok) for tok in tokens if tok) else 0
        try:
            with pd.read_csv(path, sep=sep, header=header, encoding="utf-8-sig", chunksize=rows) as chunks:
                yield from chunks
        except _damaged_file_errors() as e:
            raise DataFormatError(f"{path} is not a readable table ({type(e).__name__}: {e})") from None

    def _ngsim_chunks(self, rows: int) -> Iterator[pd.DataFrame]:
        """A raw NGSIM file in chunks, read as ``read_ngsim`` reads it."""
        import pandas as pd

        path = self.path
        first = _first_line(path)
        comma = "," in first
        tokens = [tok for tok in re.split(r"[,\s]+", first.strip()) if tok]
        header = 0 if tokens and not _is_number(tokens[0].strip('"')) else None
        try:
            with pd.read_csv(
                path,
                sep="," if comma else r"\s+",
                header=header,
                thousands="," if comma else None,
                encoding="utf-8-sig",
                skipinitialspace=True,
                chunksize=rows,
            ) as chunks:
                for df in chunks:
                    yield _name_ngsim_columns(df, path, header is None)
        except _damaged_file_errors() as e:
            raise DataFormatError(f"{path} is not a readable NGSIM file ({type(e).__name__}: {e})") from None

    # -- normalising ---------------------------------------------------------------------------

    def normalise(self, df: pd.DataFrame, row0: int) -> dict[str, Any]:
        """The columns of one chunk framing needs: ``key`` (a table of the id columns), ``scene``
        (a Series, or None), ``t, x, y`` (``vx, vy``), ``frame`` and ``hash`` (NGSIM), ``sl, sw``
        (sizes)."""
        if self.kind == "ngsim":
            return self._normalise_ngsim(df, row0)
        import pandas as pd

        where = self.path
        if self.cols is None:
            spec = self.spec
            if self.preset == "interaction" and self.given.get("id") is None and "case_id" in df.columns:
                spec["id"] = ["case_id", "track_id"]  # track ids restart in every case
            self.cols = _resolve_columns(df, self.given, spec, where, use_auto=self.preset is None)
            _check_unique_columns(df, self.cols, where)
            scale = spec.get("time_scale", 1.0) if self.time_scale is None else self.time_scale
            _check_positive("time_scale", scale)
            self.scale = float(scale)
            used = {self.cols[r] for r in ("x", "y", "vx", "vy") if r in self.cols}
            self.sizes = next((p for p in _SIZE_COLUMNS if all(c in df.columns and c not in used for c in p)), None)
        cols = self.cols
        out: dict[str, Any] = {}
        for role in ("t", "x", "y", "vx", "vy"):
            if role in cols:
                out[role] = column_floats(_numeric(df[cols[role]], cols[role], where), cols[role], where)
        if self.scale != 1.0:
            out["t"] = out["t"] * self.scale
        for role in ("t", "x", "y", "vx", "vy"):
            if role in out:
                bad = ~np.isfinite(out[role])
                if bad.any():
                    raise InvalidInputError(
                        f"{where}: column {cols[role]!r} ({role}) has missing or infinite value(s), first at row "
                        f"{row0 + int(np.flatnonzero(bad)[0])}; drop or fill those rows first"
                    )
        id_cols = list(cols["id"])
        key = pd.DataFrame({f"k{i}": df[c].to_numpy() for i, c in enumerate(id_cols)})
        out["scene"] = None
        if "scene" in cols:
            out["scene"] = pd.Series(df[cols["scene"]].to_numpy())
            if cols["scene"] not in id_cols:
                key["scene"] = out["scene"].to_numpy()
        out["key"] = key
        self._sizes(df, out)
        return out

    def _normalise_ngsim(self, df: pd.DataFrame, row0: int) -> dict[str, Any]:
        import pandas as pd

        path = self.path
        missing = [c for c in ("Vehicle_ID", "Frame_ID", "Local_X", "Local_Y") if c not in df.columns]
        if missing:
            raise DataFormatError(
                f"{path} is not an NGSIM trajectory file: no column {missing} (found {list(df.columns)}); "
                "for other tables use dpgp.read_tracks"
            )
        for col in ("Vehicle_ID", "Frame_ID", "Total_Frames", "Local_X", "Local_Y"):
            if col in df.columns:
                df[col] = _numeric(df[col], col, path)
        clash = [c for c in ("track", "t", "x", "y", "scene") if c in df.columns]
        if clash:
            raise DataFormatError(f"{path}: column(s) {clash} clash with the tracks table's own columns; rename them")
        norm = pd.DataFrame(
            {
                c: (df[c].astype(np.float64) if pd.api.types.is_numeric_dtype(df[c]) else df[c].astype(str))
                for c in df.columns
            }
        )
        frame = df["Frame_ID"].to_numpy(dtype=np.float64)
        out: dict[str, Any] = {
            "frame": frame,
            "t": frame * NGSIM_FRAME_SECONDS,
            "x": df["Local_X"].to_numpy(dtype=np.float64),
            "y": df["Local_Y"].to_numpy(dtype=np.float64),
            "hash": pd.util.hash_pandas_object(norm, index=False).to_numpy(),
        }
        for name, src in (("x", "x"), ("y", "y"), ("t", "t")):
            bad = ~np.isfinite(out[src])
            if bad.any():
                raise InvalidInputError(
                    f"{path}: missing value(s) in {name!r}, first at row {row0 + int(np.flatnonzero(bad)[0])}; "
                    "drop or fill those rows first"
                )
        key_cols = ["Vehicle_ID"] + [c for c in ("Total_Frames", "Location") if c in df.columns]
        out["key"] = pd.DataFrame({f"k{i}": df[c].to_numpy() for i, c in enumerate(key_cols)})
        out["scene"] = pd.Series(df["Location"].to_numpy()) if "Location" in df.columns else None
        if self.cols is None:
            self.cols = {}
            self.sizes = ("v_length", "v_Width") if {"v_length", "v_Width"} <= set(df.columns) else None
        self._sizes(df, out)
        return out

    def _sizes(self, df: pd.DataFrame, out: dict[str, Any]) -> None:
        """``sl, sw``: the size columns as numbers (NaN, and no size in the summary, if not)."""
        if self.sizes is None:
            return
        try:
            out["sl"] = np.asarray(df[self.sizes[0]].to_numpy(), dtype=np.float64)
            out["sw"] = np.asarray(df[self.sizes[1]].to_numpy(), dtype=np.float64)
        except (KeyError, TypeError, ValueError):
            self.sizes_ok = False  # not numeric: no size, as make_frames decides
            out["sl"] = out["sw"] = np.full(len(df), np.nan)

    def has_velocity(self) -> bool:
        return self.cols is not None and "vx" in self.cols and "vy" in self.cols


class _Registry:
    """Distinct values (rows of a key table) in the order first seen, each given a number."""

    def __init__(self) -> None:
        self.parts: list[pd.DataFrame] = []
        self.index: Any = None
        self.n = 0

    def _lookup(self, table: pd.DataFrame) -> np.ndarray:
        import pandas as pd

        if self.index is None:
            return np.full(len(table), -1, dtype=np.int64)
        if table.shape[1] == 1:
            return np.asarray(self.index.get_indexer(pd.Index(table.iloc[:, 0])), dtype=np.int64)
        return np.asarray(self.index.get_indexer(pd.MultiIndex.from_frame(table)), dtype=np.int64)

    def codes(self, table: pd.DataFrame) -> np.ndarray:
        import pandas as pd

        uniq = table.drop_duplicates(ignore_index=True)
        new = uniq[self._lookup(uniq) < 0]
        if len(new):
            self.parts = [pd.concat([*self.parts, new], ignore_index=True)]
            whole = self.parts[0]
            self.index = pd.Index(whole.iloc[:, 0]) if whole.shape[1] == 1 else pd.MultiIndex.from_frame(whole)
            self.n = len(whole)
        return self._lookup(table)

    def table(self) -> pd.DataFrame:
        return self.parts[0]


# ---------------------------------------------------------------------------------------------
# pass 1: the scan into time buckets
# ---------------------------------------------------------------------------------------------


class _Buckets:
    """Scratch files of the normalised rows, one set per (scene, time window)."""

    def __init__(self, work: str, window: float, budget: int) -> None:
        self.work, self.window, self.budget = work, window, budget
        self.files: dict[tuple[int, int], list[str]] = {}
        self.pending: dict[tuple[int, int], list[Any]] = {}
        self.n_pending = 0
        self.n_files = 0

    def add(self, cols: dict[str, np.ndarray]) -> None:
        import pyarrow as pa

        w = np.floor(cols["t"] / self.window).astype(np.int64)
        sc = cols["scene"]
        order = np.lexsort((w, sc))
        ws, ss = w[order], sc[order]
        cut = np.flatnonzero(np.r_[True, (ws[1:] != ws[:-1]) | (ss[1:] != ss[:-1]), True])
        table = pa.table({k: v[order] for k, v in cols.items()})
        for a, b in zip(cut[:-1], cut[1:]):
            self.pending.setdefault((int(ss[a]), int(ws[a])), []).append(table.slice(int(a), int(b - a)))
        self.n_pending += len(order)
        if self.n_pending >= self.budget:
            self.flush()

    def flush(self) -> None:
        import pyarrow as pa

        for key, parts in self.pending.items():
            file = os.path.join(self.work, f"b{self.n_files}.arrow")
            self.n_files += 1
            table = pa.concat_tables(parts)
            with pa.OSFile(file, "wb") as sink, pa.ipc.new_file(sink, table.schema) as writer:
                writer.write_table(table)
            self.files.setdefault(key, []).append(file)
        self.pending, self.n_pending = {}, 0

    def load(self, scenes: list[int], w: int) -> dict[str, np.ndarray] | None:
        import pyarrow as pa

        tables = []
        for s in scenes:
            for file in self.files.get((s, w), []):
                with pa.OSFile(file, "rb") as source:
                    tables.append(pa.ipc.open_file(source).read_all())
        if not tables:
            return None
        table = pa.concat_tables(tables)
        return {name: table.column(name).to_numpy() for name in table.column_names}


class _Scan(NamedTuple):
    buckets: _Buckets
    keys: _Registry
    scenes: _Registry
    n_raw: int
    t_abs: float
    span: tuple[float, float, float, float]  # x min, x max, y min, y max


def _scan(reader: _Reader, opts: _Options, work: str) -> _Scan:
    buckets = _Buckets(work, opts.window, opts.chunk_rows)
    keys, scenes = _Registry(), _Registry()
    n = 0
    t_abs = 0.0
    span = [math.inf, -math.inf, math.inf, -math.inf]
    for df in reader.raw_chunks(opts.chunk_rows):
        if len(df) == 0:
            continue
        part = reader.normalise(df, n)
        k = part.pop("key")
        sc = part.pop("scene")
        cols: dict[str, np.ndarray] = {"row": np.arange(n, n + len(df), dtype=np.int64), "key": keys.codes(k)}
        cols["scene"] = np.zeros(len(df), dtype=np.int64) if sc is None else scenes.codes(sc.to_frame("s"))
        cols.update(part)
        buckets.add(cols)
        n += len(df)
        t_abs = max(t_abs, float(np.abs(part["t"]).max()))
        span = [
            min(span[0], float(part["x"].min())),
            max(span[1], float(part["x"].max())),
            min(span[2], float(part["y"].min())),
            max(span[3], float(part["y"].max())),
        ]
    if n == 0:
        what = "has a header but no rows of data" if reader.kind == "ngsim" else "the table has no rows"
        raise DataFormatError(f"{reader.path}: {what}")
    buckets.flush()
    return _Scan(buckets, keys, scenes, n, t_abs, (span[0], span[1], span[2], span[3]))


# ---------------------------------------------------------------------------------------------
# tracks: numbering, checks, NGSIM trips, carried from bucket to bucket
# ---------------------------------------------------------------------------------------------


class _Groups(NamedTuple):
    """The order buckets are gone through: scene by scene when the tracks have scenes."""

    has_scene: bool
    members: list[list[int]]  # per group, the scene numbers (of the scan) in it
    codes: list[int]  # per group, the scene's code among the sorted scenes (0 without scenes)
    labels: np.ndarray | None  # the scenes' labels, by code
    windows: list[list[int]]  # per group, its non-empty windows, in order


def _groups(reader: _Reader, scan: _Scan) -> _Groups:
    import pandas as pd

    n_sc = max(scan.scenes.n, 1)
    if scan.scenes.n:
        values = scan.scenes.table()["s"]
        has_scene = reader.kind == "table" or values.nunique() > 1
    else:
        has_scene = False
    if has_scene:
        codes, labels = pd.factorize(values, sort=True)
        members = [[int(i)] for i in np.argsort(codes, kind="stable")]
        group_codes = [int(codes[m[0]]) for m in members]
        label_arr: np.ndarray | None = np.asarray(labels)
    else:
        members, group_codes, label_arr = [list(range(n_sc))], [0], None
    windows = []
    for m in members:
        ms = set(m)
        windows.append(sorted({w for (s, w) in scan.buckets.files if s in ms}))
    return _Groups(has_scene, members, group_codes, label_arr, windows)


class _Tracks:
    """Each bucket's rows in track order, numbered as ``read_tracks`` numbers tracks; checks
    time order (and NGSIM's duplicates and trips) against each track's last row before."""

    def __init__(self, reader: _Reader, scan: _Scan) -> None:
        import pandas as pd

        self.reader = reader
        keys = scan.keys.table()
        self.keys = keys
        id_cols = [c for c in keys.columns if c != "scene"]
        if reader.kind == "ngsim":
            rank = keys.groupby(list(keys.columns), sort=True, dropna=False).ngroup().to_numpy()
        else:
            if len(id_cols) == 1:
                rank, _ = pd.factorize(keys[id_cols[0]], sort=True, use_na_sentinel=False)
            else:
                rank = keys.groupby(id_cols, sort=True, dropna=False).ngroup().to_numpy()
            if "scene" in keys.columns:
                scode, _ = pd.factorize(keys["scene"], sort=True, use_na_sentinel=False)
                combined = scode.astype(np.int64) * (int(rank.max()) + 1) + rank
                rank = pd.factorize(combined, sort=True)[0]
        self.rank = np.asarray(rank, dtype=np.int64)
        n_keys = int(self.rank.max()) + 1
        self.n_keys = n_keys
        self.base: np.ndarray | None = None if reader.kind == "ngsim" else np.arange(n_keys, dtype=np.int64)
        self.reset()

    def reset(self) -> None:
        n = self.n_keys
        self.last = np.full(n, np.nan)  # NGSIM's last frame
        self.last_t = np.full(n, np.nan)
        self.last_row = np.full(n, -1, dtype=np.int64)
        self.trip = np.zeros(n, dtype=np.int64)
        self.n_dropped = 0

    def label(self, key: int) -> Any:
        """A key's id as the file has it (the first row of the key table with that rank)."""
        i = int(np.flatnonzero(self.rank == key)[0])
        vals = [v.item() if isinstance(v, np.generic) else v for v in self.keys.iloc[i].tolist()]
        return vals[0] if len(vals) == 1 else tuple(vals)

    def take(self, rows: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        key = self.rank[rows["key"]]
        if self.reader.kind == "ngsim":
            return self._take_ngsim(rows, key)
        t, row = rows["t"], rows["row"]
        order = np.lexsort((row, t, key))
        out = {name: rows[name][order] for name in rows if name not in ("key", "scene")}
        key, t, row = key[order], out["t"], out["row"]
        first = np.r_[True, key[1:] != key[:-1]]
        same = ~first[1:]
        rep = same & (t[1:] == t[:-1])
        if rep.any():
            i = int(np.flatnonzero(rep)[0])
            raise InvalidInputError(
                f"{self.reader.path}: time repeats inside track {self.label(int(key[i]))!r}: rows {row[i]} and "
                f"{row[i + 1]} (counted from 0) both have t={t[i]:g} s; remove the duplicate rows"
            )
        if not self.reader.sort:
            prev = np.where(first, self.last_row[key], np.r_[-1, row[:-1]])
            back = (prev >= 0) & (row < prev)
            if back.any():
                i = int(np.flatnonzero(back)[0])
                raise InvalidInputError(
                    f"{self.reader.path}: time goes backwards inside track {self.label(int(key[i]))!r}: row "
                    f"{row[i]} has t={t[i]:g} s, earlier than row {prev[i]} (rows counted from 0); pass sort=True "
                    "if the rows are merely unsorted, or fix the track ids"
                )
        last = np.r_[first[1:], True]
        self.last_row[key[last]] = row[last]
        out["step"] = t - np.where(first, self.last_t[key], np.r_[np.nan, t[:-1]])
        self.last_t[key[last]] = t[last]
        out["track"] = key
        return out

    def _take_ngsim(self, rows: dict[str, np.ndarray], key: np.ndarray) -> dict[str, np.ndarray]:
        frame, h, row = rows["frame"], rows["hash"], rows["row"]
        order = np.lexsort((row, h, frame, key))
        out = {name: rows[name][order] for name in rows if name not in ("key", "scene")}
        key = key[order]
        frame, h = out["frame"], out["hash"]
        dup = np.r_[False, (key[1:] == key[:-1]) & (frame[1:] == frame[:-1]) & (h[1:] == h[:-1])]
        if dup.any():
            keep = ~dup
            out = {name: v[keep] for name, v in out.items()}
            key, frame = key[keep], out["frame"]
            self.n_dropped += int(dup.sum())
        first = np.r_[True, key[1:] != key[:-1]]
        clash = ~first[1:] & (frame[1:] == frame[:-1])
        if clash.any():
            i = int(np.flatnonzero(clash)[0])
            raise DataFormatError(
                f"{self.reader.path}: different rows for the same vehicle trip at the same frame, Vehicle_ID "
                f"{self.label(int(key[i]))!r} at Frame_ID {frame[i]:.0f}; remove the conflicting rows (a file "
                "that joins several recordings, such as the three US-101 periods, must be split into one file "
                "per recording first)"
            )
        prev = np.where(first, self.last[key], np.r_[np.nan, frame[:-1]])
        step = frame - prev
        jump = ~np.isnan(prev) & (step * NGSIM_FRAME_SECONDS > _NGSIM_SPLIT_GAP)
        c = np.cumsum(jump)
        starts = np.flatnonzero(first)
        run = np.cumsum(first) - 1
        trip = self.trip[key] + c - (c[starts] - jump[starts])[run]
        last = np.r_[first[1:], True]
        self.last[key[last]] = frame[last]
        self.trip[key[last]] = trip[last]
        t = out["t"]
        out["step"] = np.where(jump, np.nan, t - np.where(first, self.last_t[key], np.r_[np.nan, t[:-1]]))
        self.last_t[key[last]] = t[last]
        out["key"] = key
        out["trip"] = trip
        if self.base is not None:
            out["track"] = self.base[key] + trip
        return out

    def number_trips(self) -> np.ndarray:
        """After a pass over every bucket: NGSIM's track numbers, trips in the sorted order of
        their keys, then in time. Each key's first track number, and the number of tracks last."""
        if self.base is None:
            n_trips = np.where(np.isnan(self.last), 0, self.trip + 1)
            self.base = np.r_[0, np.cumsum(n_trips)[:-1]].astype(np.int64)
            return np.r_[self.base, n_trips.sum()]
        return np.r_[self.base, self.n_keys]


def _each_bucket(scan: _Scan, groups: _Groups, tracks: _Tracks) -> Iterator[tuple[int, int, dict[str, np.ndarray]]]:
    """(group, window, rows in track order) of every non-empty bucket, in the frames' order."""
    tracks.reset()
    for g, (members, windows) in enumerate(zip(groups.members, groups.windows)):
        for w in windows:
            rows = scan.buckets.load(members, w)
            if rows is not None:
                yield g, w, tracks.take(rows)


class _Steps:
    """The steps between consecutive samples of a track, kept as a histogram of 1/64 octave
    bins (each bin's smallest and largest step), to bound the largest step below ``max_gap``."""

    _FINE = 64
    _SPAN = 64 * 64

    def __init__(self) -> None:
        self.lo = np.full(2 * self._SPAN + 1, np.inf)
        self.hi = np.full(2 * self._SPAN + 1, -np.inf)

    def add(self, steps: np.ndarray) -> None:
        steps = steps[np.isfinite(steps) & (steps > 0)]
        b = np.clip(np.floor(np.log2(steps) * self._FINE), -self._SPAN, self._SPAN).astype(np.int64) + self._SPAN
        np.minimum.at(self.lo, b, steps)
        np.maximum.at(self.hi, b, steps)

    def largest_up_to(self, limit: float) -> float:
        """At least the largest step not longer than ``limit`` (exactly it unless a bin holds
        steps on both sides of ``limit``; then ``limit``)."""
        below = self.hi <= limit
        across = (self.lo <= limit) & ~below
        best = float(self.hi[below].max()) if below.any() else 0.0
        return limit if across.any() else best


def _check_and_count(scan: _Scan, groups: _Groups, tracks: _Tracks, steps: _Steps) -> tuple[np.ndarray, int]:
    """Pass 2: checks every bucket; the rows of each track (by its number) and all rows kept;
    the steps between samples into ``steps``."""
    pairs = []
    for _, _, rows in _each_bucket(scan, groups, tracks):
        steps.add(rows["step"])
        if "trip" in rows:
            combined = rows["key"].astype(np.int64) * (1 << 31) + rows["trip"]
            u, c = np.unique(combined, return_counts=True)
            pairs.append((u // (1 << 31), u % (1 << 31), c))
        else:
            u, c = np.unique(rows["track"], return_counts=True)
            pairs.append((u, np.zeros(len(u), dtype=np.int64), c))
    base = tracks.number_trips()
    counts = np.zeros(int(base[-1]), dtype=np.int64)
    for k, trip, c in pairs:
        np.add.at(counts, base[k] + trip, c)
    return counts, int(counts.sum())


def _typical_step(scan: _Scan, groups: _Groups, tracks: _Tracks, counts: np.ndarray, n: int) -> float:
    """Pass 3: make_frames' typical step, the median of the steps it samples (every
    ``(n - 1) // 10^6``-th row of the table sorted by track, to the next row of its track).

    Exact, in memory that goes with the distinct steps sampled (at most a million), not with
    the rows: each bucket's sampled steps are merged into sorted distinct values and counts."""
    stride = max(1, (n - 1) // _TYPICAL_SAMPLE)
    offsets = np.r_[0, np.cumsum(counts)[:-1]]
    seen = np.zeros(len(counts), dtype=np.int64)
    last_t = np.full(len(counts), np.nan)
    values, weights = np.zeros(0), np.zeros(0, dtype=np.int64)
    for _, _, rows in _each_bucket(scan, groups, tracks):
        tr, t = rows["track"], rows["t"]
        first = np.r_[True, tr[1:] != tr[:-1]]
        starts = np.flatnonzero(first)
        rank = np.arange(len(tr)) - starts[np.cumsum(first) - 1] + seen[tr]
        prev = np.where(first, last_t[tr], np.r_[np.nan, t[:-1]])
        pick = (rank > 0) & ((offsets[tr] + rank - 1) % stride == 0)
        last = np.r_[first[1:], True]
        seen[tr[last]] = rank[last] + 1
        last_t[tr[last]] = t[last]
        u, c = np.unique((t - prev)[pick], return_counts=True)
        values, inverse = np.unique(np.r_[values, u], return_inverse=True)
        weights = np.bincount(inverse, weights=np.r_[weights, c], minlength=len(values)).astype(np.int64)
    total = int(weights.sum())
    if total == 0:
        return 0.0
    ranks = sorted({(total - 1) // 2, total // 2})  # the middle value, or the two middle values
    middle = values[np.searchsorted(np.cumsum(weights), ranks, side="right")]
    return float(np.median(middle))  # as np.median of all of them: the mean of the middle two


# ---------------------------------------------------------------------------------------------
# pass 4: framing, window by window, with the summary's counts of segments
# ---------------------------------------------------------------------------------------------


class _Segments:
    """The framing summary's counts of segments and gaps, as the buckets go by in time order:
    each track's open segment (first time, rows, last time) is carried to the next bucket."""

    def __init__(self, n_tracks: int, n_scenes: int, dt: float, max_gap: float, opts: _Options, mode: str) -> None:
        self.dt, self.mode, self.smoothing = dt, mode, opts.smoothing
        self.limit = max_gap * (1 + 1e-9)
        self.eps = _GRID_EPS * min(1.0, 1.0 / dt)
        self.last_t = np.full(n_tracks, np.nan)
        self.s0 = np.zeros(n_tracks)
        self.length = np.zeros(n_tracks, dtype=np.int64)
        self.scene = np.zeros(n_tracks, dtype=np.int64)
        self.lo_k = np.full(n_scenes, np.iinfo(np.int64).max)
        self.hi_k = np.full(n_scenes, np.iinfo(np.int64).min)
        self.used = np.zeros(n_scenes, dtype=bool)
        self.c: dict[str, Any] = dict(
            n_segments=0, n_gaps=0, n_gap_times=0, n_segments_between_grid_times=0, n_rows_between_grid_times=0,
            n_single_sample_segments=0, n_unsmoothed_segments=0, n_resampled=0,
        )  # fmt: skip

    def add(self, tr: np.ndarray, t: np.ndarray, scene: int) -> None:
        n = len(tr)
        self.scene[tr] = scene
        first = np.r_[True, tr[1:] != tr[:-1]]
        prev = np.where(first, self.last_t[tr], np.r_[np.nan, t[:-1]])
        has = ~np.isnan(prev)
        gap = has & (t - prev > self.limit)
        new = ~has | gap
        self.c["n_gaps"] += int(gap.sum())
        k1p = np.floor(prev[gap] / self.dt + self.eps).astype(np.int64)
        k0n = np.ceil(t[gap] / self.dt - self.eps).astype(np.int64)
        self.c["n_gap_times"] += int(np.maximum(k0n - k1p - 1, 0).sum())
        shut = first & gap  # the open segment carried from before ends at a gap here
        st = tr[shut]
        self._close(self.s0[st], self.last_t[st], self.length[st], self.scene[st])
        rs = np.flatnonzero(first | new)
        re = np.r_[rs[1:], n]
        run_tr, run_len, run_s0, run_s1 = tr[rs], re - rs, t[rs].copy(), t[re - 1]
        cont = first[rs] & ~new[rs]
        run_s0[cont] = self.s0[run_tr[cont]]
        run_len[cont] += self.length[run_tr[cont]]
        last = np.r_[run_tr[1:] != run_tr[:-1], True]
        done = ~last
        self._close(run_s0[done], run_s1[done], run_len[done], self.scene[run_tr[done]])
        keep = run_tr[last]
        self.s0[keep], self.length[keep], self.last_t[keep] = run_s0[last], run_len[last], run_s1[last]

    def finish(self) -> None:
        st = np.flatnonzero(~np.isnan(self.last_t))
        self._close(self.s0[st], self.last_t[st], self.length[st], self.scene[st])
        self.last_t[:] = np.nan

    def _close(self, s0: np.ndarray, s1: np.ndarray, length: np.ndarray, scene: np.ndarray) -> None:
        if not len(s0):
            return
        k0 = np.ceil(s0 / self.dt - self.eps).astype(np.int64)
        k1 = np.floor(s1 / self.dt + self.eps).astype(np.int64)
        cnt = np.maximum(k1 - k0 + 1, 0)
        between = cnt == 0
        single = (length == 1) & ~between if self.mode == "diff" else np.zeros(len(s0), dtype=bool)
        cnt[single] = 0
        c = self.c
        c["n_segments"] += len(s0)
        c["n_segments_between_grid_times"] += int(between.sum())
        c["n_rows_between_grid_times"] += int(length[between].sum())
        c["n_single_sample_segments"] += int(single.sum())
        if self.smoothing is not None:
            c["n_unsmoothed_segments"] += int(((length < self.smoothing[0]) & (cnt > 0)).sum())
        c["n_resampled"] += int(cnt.sum())
        self.used[scene] = True
        has = cnt > 0
        np.minimum.at(self.lo_k, scene[has], k0[has])
        np.maximum.at(self.hi_k, scene[has], k1[has])

    def n_slots(self) -> int:
        ok = self.hi_k >= self.lo_k
        return int((self.hi_k[ok] - self.lo_k[ok] + 1).sum())


class _Spool:
    """The frames, in order, in a scratch Parquet file; each frame's scene, grid number and size
    in memory (what the shard cuts and the manifest need)."""

    def __init__(self, work: str) -> None:
        self.file = os.path.join(work, "frames.parquet")
        self.writer: Any = None
        self.scene: list[np.ndarray] = []
        self.k: list[np.ndarray] = []
        self.size: list[np.ndarray] = []

    def add(self, scene: int, k: np.ndarray, cols: dict[str, np.ndarray]) -> None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        new = np.r_[True, k[1:] != k[:-1]]
        starts = np.flatnonzero(new)
        self.k.append(k[starts])
        self.scene.append(np.full(len(starts), scene, dtype=np.int64))
        self.size.append(np.diff(np.r_[starts, len(k)]))
        table = pa.table(cols)
        if self.writer is None:
            self.writer = pq.ParquetWriter(self.file, table.schema)
        self.writer.write_table(table)

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()

    def frames(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        cat = np.concatenate
        if not self.k:
            return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
        return cat(self.scene), cat(self.k), cat(self.size)

    def parts(self, sizes: list[int]) -> Iterator[Any]:
        """The spooled rows cut into consecutive tables of ``sizes`` rows."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        batches = pq.ParquetFile(self.file).iter_batches(batch_size=1 << 16)
        held: list[Any] = []
        n_held = 0
        for want in sizes:
            while n_held < want:
                b = next(batches)
                held.append(b)
                n_held += b.num_rows
            table = pa.Table.from_batches(held)
            yield table.slice(0, want)
            rest = table.slice(want)
            held, n_held = rest.to_batches(), rest.num_rows


class _Part(NamedTuple):
    """What ``_shardfile._write_shard`` reads of frames: one shard's."""

    ids: np.ndarray
    offsets: np.ndarray
    xy: np.ndarray
    v: np.ndarray
    tracks: np.ndarray
    labels: None
    prev_v: np.ndarray
    prev_heading: np.ndarray


def _frame_all(
    scan: _Scan,
    groups: _Groups,
    tracks: _Tracks,
    opts: _Options,
    max_gap: float,
    step: float,
    n_tracks: int,
    spool: _Spool,
) -> tuple[_Segments, np.ndarray, str]:
    """Pass 4: every window framed into the spool; the summary's segment counts, each track's
    size (its first row's), and the velocity mode used. ``step``: at least the longest step
    between consecutive samples of a segment."""
    import pandas as pd

    dt, W = opts.dt, opts.window
    mode = (
        "columns"
        if (opts.velocity == "auto" and tracks.reader.has_velocity()) or opts.velocity == "columns"
        else "diff"
    )
    n_scenes = 1 if groups.labels is None else len(groups.labels)
    segs = _Segments(n_tracks, n_scenes, dt, max_gap, opts, mode)
    # A grid point looks at samples up to w + 1 rows either side of its two neighbours (w: the
    # smoothing window, or 3 for differences), each row at most `step` from the next: more than
    # enough when the window's rows reach `margin` seconds beyond it on both sides.
    rows_seen = (opts.smoothing[0] if opts.smoothing else 3) + 4
    margin = rows_seen * step * 1.01 + dt
    nb = int(math.ceil(margin / W))  # buckets of context either side
    ng = int(math.ceil(step / W)) + 1  # windows beyond a bucket that may hold its grid points
    sizes = np.full((n_tracks, 2), np.nan)
    sized = np.zeros(n_tracks, dtype=bool)
    with_v = tracks.reader.has_velocity()
    # each track's last grid point (inside the ROI or not) so far, for the next window's
    # previous steps: a stopped vehicle's heading may come from many windows back
    carry = PerTrack(n_tracks)
    stub = pd.DataFrame()
    stub.attrs["dpgp"] = {"units": tracks.reader.units}
    length_unit = describe_tracks(stub, opts.units_name, opts.scale)["length_unit"]
    tracks.reset()
    for members, code, windows in zip(groups.members, groups.codes, groups.windows):
        todo = sorted({w + d for w in windows for d in range(-ng, ng + 1)})
        held: dict[int, dict[str, np.ndarray]] = {}
        nxt = 0
        for w in todo:
            while nxt < len(windows) and windows[nxt] <= w + nb:
                b = windows[nxt]
                nxt += 1
                loaded = scan.buckets.load(members, b)
                if loaded is None:
                    continue
                rows = tracks.take(loaded)
                segs.add(rows["track"], rows["t"], code)
                if "sl" in rows:  # each track's size is its first row's
                    firsts = np.flatnonzero(np.r_[True, rows["track"][1:] != rows["track"][:-1]])
                    trk = rows["track"][firsts]
                    new = ~sized[trk]
                    sizes[trk[new]] = np.column_stack([rows["sl"][firsts[new]], rows["sw"][firsts[new]]])
                    sized[trk[new]] = True
                held[b] = rows
            for b in [b for b in held if b < w - nb]:
                del held[b]
            # the window's rows and those within the margin: each track's rows over one time span
            lo, hi = w * W - margin, (w + 1) * W + margin
            names = ("track", "t", "x", "y", "vx", "vy") if with_v else ("track", "t", "x", "y")
            ctx = []
            for b in sorted(held):
                r = held[b]
                near = slice(None) if b == w else (r["t"] >= lo) & (r["t"] <= hi)
                ctx.append({name: r[name][near] for name in names})
            if not any(len(r["t"]) for r in ctx):
                continue
            tr = np.concatenate([r["track"] for r in ctx])
            order = np.argsort(tr, kind="stable")
            table = {name: np.concatenate([r[name] for r in ctx])[order] for name in names}
            res = _resample(
                pd.DataFrame(table),
                opts.roi,
                dt,
                opts.velocity,
                opts.smoothing,
                opts.units,
                max_gap,
                partial=True,
                heading_min_speed=opts.heading_min_speed,
                length_unit=length_unit,
                carry=carry,
                keep=_window_keeper(dt, W, w),
            )
            if res is None:  # none of the window's own grid points (keep) lies in the ROI
                continue
            k = res["k"]
            trk = res["track_labels"][res["track"]].astype(np.int64)
            order = np.lexsort((trk, k))
            spool.add(
                code,
                k[order],
                {
                    "track": trk[order],
                    **{name: res[name][order] for name in ("x", "y", "vx", "vy", "pvx", "pvy", "ph")},
                },
            )
    segs.finish()
    spool.close()
    return segs, sizes, mode


def _window_keeper(dt: float, W: float, w: int) -> Any:
    """Which grid numbers are window ``w``'s own: those whose time falls in it. The framing of
    the window keeps only these (the margins' points are other windows'), before its ROI crop and
    its previous steps, which carry each track on to the next window."""
    return lambda k: np.floor(k * dt / W).astype(np.int64) == w


# ---------------------------------------------------------------------------------------------
# the whole
# ---------------------------------------------------------------------------------------------


def _run(reader: _Reader, opts: _Options, n_shards: int, tmp: str, work: str) -> dict[str, Any]:
    """Every pass; the shards written into ``tmp``; the manifest's document."""
    import pandas as pd

    scan = _scan(reader, opts, work)
    if opts.velocity == "columns" and not reader.has_velocity():
        raise DataFormatError("velocity='columns' needs vx and vy columns in the table; use velocity='diff'")
    groups = _groups(reader, scan)
    tracks = _Tracks(reader, scan)
    steps = _Steps()
    counts, n = _check_and_count(scan, groups, tracks, steps)
    n_tracks = len(counts)
    dt = opts.dt
    max_gap = opts.max_gap
    if max_gap is None:
        max_gap = 2.0 * max(dt, _typical_step(scan, groups, tracks, counts, n))
    if scan.t_abs / dt > _MAX_GRID_NUMBER:
        raise InvalidInputError(
            f"dt={dt:g} s is too small for times up to {scan.t_abs:g} s: grid numbers would exceed 2^52 and lose "
            "precision; use a larger dt, or subtract the start time from t"
        )
    spool = _Spool(work)
    # the longest step inside a segment: how far apart (in time) the samples a point looks at can be
    reach = steps.largest_up_to(max_gap * (1 + 1e-9))
    segs, sizes, mode = _frame_all(scan, groups, tracks, opts, max_gap, reach, n_tracks, spool)
    c = segs.c
    if c["n_resampled"] == 0:
        raise InvalidInputError(
            f"no track reaches a grid time: dt={dt:g} s is longer than every track's time span "
            f"(and max_gap={max_gap:g} s cuts tracks at longer gaps); use a smaller dt or a larger max_gap"
        )
    f_scene, f_k, f_size = spool.frames()
    n_points = int(f_size.sum())
    if n_points == 0:
        raise InvalidInputError(
            "no vehicle enters the ROI x [{:g}, {:g}], y [{:g}, {:g}]".format(*(opts.roi or (0, 0, 0, 0)))
            + ": the data span x [{:g}, {:g}], y [{:g}, {:g}]".format(*scan.span)
            + " (the ROI is in the table's units, before any units conversion)"
        )
    n_frames = len(f_k)
    n_shards = sf.check_shards(n_shards, n_frames)
    size_table = pd.DataFrame({"track": np.arange(n_tracks)})
    if reader.sizes is not None and reader.sizes_ok:
        size_table[reader.sizes[0]], size_table[reader.sizes[1]] = sizes[:, 0], sizes[:, 1]
    size_table.attrs["dpgp"] = {"units": reader.units, "format": reader.fmt}
    summary = FramingSummary(
        dt=dt,
        max_gap=max_gap,
        units=opts.units_name,
        velocity=mode,
        smoothing=opts.smoothing,
        roi=None if opts.roi is None else tuple(float(r * opts.scale) for r in opts.roi),  # type: ignore[arg-type]
        n_rows=n,
        n_tracks=n_tracks,
        **c,
        n_outside_roi=c["n_resampled"] - n_points,
        n_points=n_points,
        n_frames=n_frames,
        n_empty_frames=segs.n_slots() - n_frames,
        n_scenes=int(segs.used.sum()) if groups.has_scene else 1,
        **describe_tracks(size_table, opts.units_name, opts.scale),
    )
    times = np.round(f_k * dt, 9)
    offsets = np.r_[0, np.cumsum(f_size)].astype(np.int64)
    bounds = sf.shard_bounds(offsets, n_shards)
    step = (f_scene[1:] == f_scene[:-1]) & (np.abs(np.diff(times) - dt) <= 1e-6 * max(1.0, dt))
    prev = np.where(np.r_[False, step], np.arange(n_frames) - 1, -1)
    order, continues = sf.time_info(f_scene, times, dt, prev, bounds)
    infos = sf.shard_infos(offsets, bounds, continues)
    labels = groups.labels
    ids_spec: dict[str, Any] = {"kind": "array", "dtype": times.dtype.str} if labels is None else {"kind": "pair"}
    for i, (info, part) in enumerate(zip(infos, spool.parts([s.points for s in infos]))):
        a, b = info.start, info.stop
        if labels is None:
            ids = times[a:b]
        else:
            ids = np.empty(b - a, dtype=object)
            ids[:] = list(zip(labels[f_scene[a:b]].tolist(), times[a:b].tolist()))
        cols = {name: part.column(name).to_numpy() for name in ("x", "y", "vx", "vy", "track", "pvx", "pvy", "ph")}
        frames = _Part(
            ids,
            offsets[a : b + 1] - offsets[a],
            np.column_stack([cols["x"], cols["y"]]),
            np.column_stack([cols["vx"], cols["vy"]]),
            cols["track"],
            None,
            np.column_stack([cols["pvx"], cols["pvy"]]),
            cols["ph"],
        )
        sf._write_shard(os.path.join(tmp, info.file), frames, info, i, n_shards, ids_spec, None, first=a)
    return sf.manifest_doc(n_frames, infos, ids_spec, None, True, summary, order, opts.heading_min_speed)


__all__ = ["frame_to_shards"]
