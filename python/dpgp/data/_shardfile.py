"""The on-disk format of sharded frames (issue 33): a directory of Parquet shards and a JSON
manifest, written atomically. :mod:`.shards` is the public face; this module sits below
:mod:`.frames` (which uses it for ``Frames.to_parquet`` and ``read_frames(directory)``), so it
never builds a :class:`~dpgp.Frames`: it writes any object with a ``Frames``' attributes and
reads arrays.

::

    frames/
      manifest.json          what the directory holds (below)
      shard-00000.parquet    frames [0, a)
      shard-00001.parquet    frames [a, b)
      ...

**Shards.** Each holds a contiguous range of the frames, in their order (frames made by
:func:`dpgp.make_frames` are in recording order, scene by scene), so a worker reads its own shard
alone. Ranges are cut so that shards hold about the same number of vehicle observations (the
work of a sweep), every shard at least one frame. One row per vehicle observation:

``frame_number``  int64, the frame's position in the whole set (``start`` .. ``stop - 1``)
``frame``         the frame's id; for ``(scene, time)`` ids the time, with the scene in ``scene``
``x, y, vx, vy``  float64
``track``         int64 track id, when the frames keep them
``prev_vx, prev_vy, prev_heading``  float64, NaN where none: each vehicle's previous velocity
                  and carried heading (:mod:`._previous`), when the frames carry them
``label``         the frame's label, when the frames carry labels

Values of a frame (id, label) repeat on each of its rows; Parquet stores such runs compactly.
The schema metadata ``dpgp`` of a shard names its number, the number of shards and its frame
range, checked against the manifest when it is read (a shard of another write is refused).

**Manifest** (``manifest.json``): ``format`` and ``version``; ``n_frames``, ``n_points``;
``shards``, one entry each: ``file``, ``frames`` ``[start, stop)``, ``points`` and ``continues``
(its first frame is the one recorded right after the previous shard's last, so a run of
consecutive frames crosses the boundary; ``null`` when the frames have no time order);
``ids`` and ``labels`` (how they are stored: ``{"kind": "array", "dtype": ...}``, ``"object"``,
or ``"pair"`` for ``(scene, time)`` ids; ``labels`` is ``null`` without labels); ``tracks``
(whether rows carry track ids); ``units`` (the positions' length unit, ``"m"``/``"ft"``, or
``null``); ``summary`` (the :class:`~dpgp.FramingSummary`: how the frames were made, with the
framing provenance, or ``null``); ``time_order`` (``dt``, ``in_time_order``: whether the frames
are in recording order, ``n_sequences``: runs of consecutive frames; ``null`` when the ids are
not times, see :mod:`.timeorder`); ``previous`` (``{"heading_min_speed": m/s}`` when the rows
carry previous velocities and headings; absent or ``null`` otherwise: directories written before
issue 34 read as frames without them, and older readers ignore the columns, so the version
stays 1); ``written_by``.

**Atomic.** Everything is written into a temporary directory beside the target (named
``.dpgp-<name>-*.tmp``), synced, then renamed onto it: a failed or interrupted write leaves no
half-written directory, and an existing one is replaced only whole.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import uuid
from dataclasses import dataclass
from typing import Any, NamedTuple, TypeGuard

import numpy as np

from .._arrays import as_path
from ..exceptions import DataFormatError, InvalidInputError, UnorderedFramesError
from .provenance import FramingSummary
from .timeorder import time_order

FORMAT = "dpgp sharded frames"
#: The format version this dpgp writes, and the newest it reads.
VERSION = 1
MANIFEST = "manifest.json"
_META_KEY = b"dpgp"
#: numpy kinds stored as a typed Parquet column and restored to their dtype.
_ARRAY_KINDS = "biufUmM"
_FLOATS = ("x", "y", "vx", "vy")
_PREVIOUS = ("prev_vx", "prev_vy", "prev_heading")


@dataclass(frozen=True)
class ShardInfo:
    """One shard: its ``file`` in the directory, its frames ``start`` .. ``stop - 1`` (global
    positions), its vehicle observations ``points``, and whether its first frame ``continues``
    the previous shard's last in time (``None`` when the frames have no time order)."""

    file: str
    start: int
    stop: int
    points: int
    continues: bool | None

    @property
    def n_frames(self) -> int:
        return self.stop - self.start


@dataclass(frozen=True)
class ShardManifest:
    """What a directory of sharded frames holds, read from its ``manifest.json`` alone.

    ``summary`` is the frames' :class:`~dpgp.FramingSummary` (``None`` for frames not made by
    :func:`dpgp.make_frames`); ``units`` their length unit; ``dt``, ``in_time_order`` and
    ``n_sequences`` describe their time order (``dt`` is ``None`` when the ids are not times)."""

    directory: str
    version: int
    n_frames: int
    n_points: int
    shards: tuple[ShardInfo, ...]
    ids: dict[str, Any]
    labels: dict[str, Any] | None
    tracks: bool
    units: str | None
    summary: FramingSummary | None
    dt: float | None
    in_time_order: bool
    n_sequences: int | None
    heading_min_speed: float | None = None  # rows carry prev_vx, prev_vy, prev_heading (issue 34)

    @property
    def n_shards(self) -> int:
        return len(self.shards)

    @property
    def has_headings(self) -> bool:
        """Whether the rows carry previous velocities and headings (the manifest names their speed)."""
        return self.heading_min_speed is not None

    def path(self, i: int) -> str:
        """The file of shard ``i``."""
        return os.path.join(self.directory, self.shards[i].file)


class StoredFrames(NamedTuple):
    """The arrays of :class:`~dpgp.Frames`, read from shards (offsets from 0)."""

    ids: np.ndarray
    offsets: np.ndarray
    xy: np.ndarray
    v: np.ndarray
    labels: np.ndarray | None
    tracks: np.ndarray | None
    summary: FramingSummary | None
    prev_v: np.ndarray | None = None
    prev_heading: np.ndarray | None = None
    heading_min_speed: float | None = None


# ---------------------------------------------------------------------------------------------
# writing
# ---------------------------------------------------------------------------------------------


def check_shards(shards: Any, n_frames: int | None = None) -> int:
    """``shards`` as a number of shards: a whole number from 1 to the number of frames."""
    if isinstance(shards, (bool, np.bool_)) or not isinstance(shards, (int, np.integer)):
        raise InvalidInputError(f"shards must be a whole number of shards (1 or more), got {shards!r}")
    if shards < 1:
        raise InvalidInputError(f"shards must be 1 or more, got {shards}")
    if n_frames is not None and shards > n_frames:
        raise InvalidInputError(
            f"shards={shards} is more than the {n_frames} frames: every shard holds at least one frame"
        )
    return int(shards)


def check_target(directory: Any, overwrite: bool) -> str:
    """The target directory's path, refused (``FileExistsError``) before any work when it is a
    file, or a non-empty directory without ``overwrite``, or a non-empty directory that does not
    hold sharded frames (``overwrite`` replaces only those: never a directory of other files)."""
    if not isinstance(overwrite, (bool, np.bool_)):
        raise InvalidInputError(f"overwrite must be True or False, got {overwrite!r}")
    try:
        path = os.path.realpath(as_path(directory))  # a symbolic link: the directory it names
    except TypeError:
        raise InvalidInputError(
            f"the directory for sharded frames must be a path, got {type(directory).__name__}"
        ) from None
    if not os.path.isdir(os.path.dirname(path)):
        raise FileNotFoundError(
            2, "the directory to write the sharded frames into does not exist", os.path.dirname(path)
        )
    if os.path.lexists(path) and not os.path.isdir(path):
        raise FileExistsError(17, "sharded frames are a directory, and this path is a file; give a new path", path)
    if os.path.isdir(path) and os.listdir(path):
        if not overwrite:
            raise FileExistsError(
                17, "the directory is not empty; pass overwrite=True to replace sharded frames there", path
            )
        if not _holds_sharded_frames(path):
            raise FileExistsError(
                17,
                f"the directory is not empty and holds no sharded frames (no dpgp {MANIFEST}); overwrite=True "
                "replaces only sharded frames, never other files. Give a new or empty directory",
                path,
            )
    return path


def shard_bounds(offsets: np.ndarray, n_shards: int) -> np.ndarray:
    """Frame positions ``[0, c_1, ..., n]`` that cut the frames into ``n_shards`` contiguous
    ranges of about equal numbers of vehicle observations, each at least one frame."""
    offsets = np.asarray(offsets, dtype=np.int64)
    n = len(offsets) - 1
    k = np.arange(1, n_shards, dtype=np.int64)
    # the first frame that starts at or after each k/n_shards of the observations ...
    cut = np.searchsorted(offsets, offsets[-1] * k / n_shards, side="left").astype(np.int64)
    # ... moved just enough that the cuts strictly increase and leave every shard a frame
    gap = np.clip(np.maximum.accumulate(cut - k) if len(k) else cut - k, 0, n - n_shards)
    return np.r_[0, gap + k, n].astype(np.int64)


def write_shards(frames: Any, directory: Any, shards: Any, *, overwrite: bool = False) -> ShardManifest:
    """Write ``frames`` (a :class:`~dpgp.Frames`) as a directory of ``shards`` Parquet files
    and a manifest, atomically; the manifest written. See the module docstring."""
    n_frames = len(frames.ids)
    n_shards = check_shards(shards, n_frames)
    path = check_target(directory, overwrite)
    _pyarrow()
    ids_spec = _spec("frame ids", frames.ids, pair=True)
    labels_spec = None if frames.labels is None else _spec("labels", frames.labels, pair=False)
    offsets = np.asarray(frames.offsets, dtype=np.int64)
    bounds = shard_bounds(offsets, n_shards)
    order, continues = _time_info(frames, bounds)
    infos = shard_infos(offsets, bounds, continues)
    doc = manifest_doc(
        n_frames,
        infos,
        ids_spec,
        labels_spec,
        frames.tracks is not None,
        getattr(frames, "summary", None),
        order,
        getattr(frames, "heading_min_speed", None) if getattr(frames, "prev_v", None) is not None else None,
    )
    parent = os.path.dirname(path)
    tmp = tempfile.mkdtemp(prefix=temp_prefix(path), suffix=".tmp", dir=parent)
    try:
        for i, info in enumerate(infos):
            _write_shard(os.path.join(tmp, info.file), frames, info, i, n_shards, ids_spec, labels_spec)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return commit(tmp, path, doc)


def shard_infos(offsets: np.ndarray, bounds: np.ndarray, continues: list[bool | None]) -> list[ShardInfo]:
    """The manifest's entries of shards cut at frame positions ``bounds`` (:func:`shard_bounds`)."""
    n_shards = len(bounds) - 1
    return [
        ShardInfo(
            file=f"shard-{i:0{max(5, len(str(n_shards - 1)))}d}.parquet",
            start=int(bounds[i]),
            stop=int(bounds[i + 1]),
            points=int(offsets[bounds[i + 1]] - offsets[bounds[i]]),
            continues=continues[i],
        )
        for i in range(n_shards)
    ]


def manifest_doc(
    n_frames: int,
    infos: list[ShardInfo],
    ids_spec: dict[str, Any],
    labels_spec: dict[str, Any] | None,
    tracks: bool,
    summary: FramingSummary | None,
    order: dict[str, Any] | None,
    heading_min_speed: float | None = None,
) -> dict[str, Any]:
    """The manifest's JSON document (the module docstring lists its fields); ``heading_min_speed``
    when the rows carry previous velocities and headings."""
    previous = None if heading_min_speed is None else {"heading_min_speed": float(heading_min_speed)}
    return {
        "format": FORMAT,
        "version": VERSION,
        "n_frames": n_frames,
        "n_points": sum(s.points for s in infos),
        "n_shards": len(infos),
        "shards": [
            {"file": s.file, "frames": [s.start, s.stop], "points": s.points, "continues": s.continues} for s in infos
        ],
        "ids": ids_spec,
        "labels": labels_spec,
        "tracks": tracks,
        "units": None if summary is None else summary.length_unit,
        "summary": None if summary is None else summary.to_dict(),
        "time_order": order,
        "previous": previous,
        "written_by": f"dpgp {_version()}",
    }


def commit(tmp: str, path: str, doc: dict[str, Any]) -> ShardManifest:
    """Finish a write: the manifest ``doc`` into the temporary directory ``tmp`` (which holds
    the shards), synced, and ``tmp`` renamed onto ``path`` (the target ``check_target`` gave).
    ``tmp`` is removed if this fails."""
    parent = os.path.dirname(path)
    try:
        with open(os.path.join(tmp, MANIFEST), "w", encoding="utf-8") as fh:
            json.dump(doc, fh, indent=1, default=_json_value)
            fh.write("\n")
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, _directory_mode())
        _sync(tmp)
        _move_into_place(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    _sync(parent)
    return parse_manifest(json.loads(json.dumps(doc, default=_json_value)), path, os.path.join(path, MANIFEST))


def temp_prefix(path: str) -> str:
    """The prefix of the temporary directory a write of ``path`` goes through: named after it,
    so that the leftover of a writer killed mid-write (SIGKILL runs no cleanup) can be found."""
    return f".dpgp-{os.path.basename(path)[:64]}-"


def _spec(what: str, values: Any, pair: bool) -> dict[str, Any]:
    """How per-frame ``values`` are stored: a typed column, Python objects, or (scene, time)."""
    values = np.asarray(values)
    if values.dtype.kind in _ARRAY_KINDS:
        return {"kind": "array", "dtype": values.dtype.str}
    if values.dtype.kind == "O":
        items = values.tolist()
        if pair and items and all(isinstance(x, tuple) and len(x) == 2 for x in items):
            return {"kind": "pair"}
        return {"kind": "object"}
    raise InvalidInputError(
        f"{what} of dtype {values.dtype} cannot be stored in Parquet; use numbers, strings or (scene, time) pairs"
    )


def _columns(spec: dict[str, Any], values: np.ndarray, sizes: np.ndarray, name: str, what: str) -> dict[str, Any]:
    """Per-frame ``values`` of one shard as row columns (each frame's value on each of its rows)."""
    import pyarrow as pa

    try:
        if spec["kind"] == "array":
            return {name: pa.array(np.repeat(values, sizes))}
        if spec["kind"] == "pair":
            scenes = np.empty(len(values), dtype=object)
            times = np.empty(len(values), dtype=object)
            scenes[:] = [x[0] for x in values]
            times[:] = [x[1] for x in values]
            return {"scene": pa.array(np.repeat(scenes, sizes)), name: pa.array(np.repeat(times, sizes))}
        return {name: pa.array(np.repeat(values, sizes))}
    except (pa.ArrowException, TypeError, ValueError) as e:
        raise InvalidInputError(
            f"{what} cannot be stored in Parquet ({e}); use numbers, strings or (scene, time) pairs, one kind each"
        ) from None


def _write_shard(
    file: str,
    frames: Any,
    info: ShardInfo,
    i: int,
    n_shards: int,
    ids_spec: dict[str, Any],
    labels_spec: dict[str, Any] | None,
    first: int = 0,
) -> None:
    """One shard file, built from the rows of its frames only (never a copy of all frames).
    ``frames`` may hold only some of the frames, from global position ``first`` on."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    a, b = info.start - first, info.stop - first
    r0, r1 = int(frames.offsets[a]), int(frames.offsets[b])
    sizes: np.ndarray = np.diff(np.asarray(frames.offsets[a : b + 1], dtype=np.int64))
    cols: dict[str, Any] = {
        "frame_number": pa.array(np.repeat(np.arange(info.start, info.stop, dtype=np.int64), sizes))
    }
    cols.update(_columns(ids_spec, np.asarray(frames.ids)[a:b], sizes, "frame", "frame ids"))
    xy, v = frames.xy[r0:r1], frames.v[r0:r1]
    for name, col in zip(_FLOATS, (xy[:, 0], xy[:, 1], v[:, 0], v[:, 1])):
        cols[name] = pa.array(np.ascontiguousarray(col, dtype=np.float64))
    if frames.tracks is not None:
        cols["track"] = pa.array(np.ascontiguousarray(frames.tracks[r0:r1], dtype=np.int64))
    prev_v, prev_h = getattr(frames, "prev_v", None), getattr(frames, "prev_heading", None)
    if prev_v is not None and prev_h is not None:
        for name, col in zip(_PREVIOUS, (prev_v[r0:r1, 0], prev_v[r0:r1, 1], prev_h[r0:r1])):
            cols[name] = pa.array(np.ascontiguousarray(col, dtype=np.float64))  # NaN stays a value, not a null
    if labels_spec is not None:
        cols.update(_columns(labels_spec, np.asarray(frames.labels)[a:b], sizes, "label", "labels"))
    meta = {
        "format": FORMAT,
        "version": VERSION,
        "shard": i,
        "n_shards": n_shards,
        "frames": [info.start, info.stop],
        "points": r1 - r0,
    }
    table = pa.table(cols).replace_schema_metadata({_META_KEY: json.dumps(meta).encode()})
    with open(file, "wb") as fh:
        pq.write_table(table, fh)
        fh.flush()
        os.fsync(fh.fileno())


def _time_info(frames: Any, bounds: np.ndarray) -> tuple[dict[str, Any] | None, list[bool | None]]:
    """The manifest's ``time_order`` and each shard's ``continues``; ``None`` for frames whose
    ids are not times."""
    n_shards = len(bounds) - 1
    try:
        order = time_order(frames)
    except UnorderedFramesError:
        return None, [None] * n_shards
    return time_info(order.scene, order.time, order.dt, order.prev, bounds)


def time_info(
    scene: np.ndarray, t: np.ndarray, dt: float, prev: np.ndarray, bounds: np.ndarray
) -> tuple[dict[str, Any], list[bool | None]]:
    """The manifest's ``time_order`` and each shard's ``continues``, from the frames' scene codes,
    times and the position of each one's predecessor in time (``-1``: none; :mod:`.timeorder`)."""
    forward = (scene[1:] > scene[:-1]) | ((scene[1:] == scene[:-1]) & (t[1:] > t[:-1]))
    info = {"dt": dt, "in_time_order": bool(forward.all()), "n_sequences": int((prev < 0).sum())}
    continues: list[bool | None] = [False]
    continues += [bool(prev[a] == a - 1) for a in bounds[1:-1]]
    return info, continues


def _move_into_place(tmp: str, path: str) -> None:
    """Rename the finished temporary directory onto ``path``: into a free or empty place, or in
    exchange for the sharded frames there (``check_target`` allowed that), which are then
    removed. If the second rename fails the old directory is put back."""
    if os.path.isdir(path) and os.listdir(path):
        old = os.path.join(os.path.dirname(path), f"{temp_prefix(path)}{uuid.uuid4().hex[:12]}.old")
        os.rename(path, old)
        try:
            os.rename(tmp, path)
        except BaseException:
            os.rename(old, path)
            raise
        shutil.rmtree(old, ignore_errors=True)
        return
    if os.path.isdir(path):
        os.rmdir(path)  # empty: a rename onto it is refused on some systems
    os.rename(tmp, path)


def _holds_sharded_frames(path: str) -> bool:
    try:
        with open(os.path.join(path, MANIFEST), "rb") as fh:
            doc = json.loads(fh.read())
    except (OSError, ValueError):
        return False
    return isinstance(doc, dict) and doc.get("format") == FORMAT


def _sync(directory: str) -> None:
    """fsync a directory (its entries), where the system allows it."""
    try:
        fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _directory_mode() -> int:
    """The mode a plain ``os.mkdir`` would give (mkdtemp's is 0700)."""
    umask = os.umask(0)
    os.umask(umask)
    return 0o777 & ~umask


def _json_value(x: Any) -> Any:
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f"{type(x).__name__} is not JSON")


def _version() -> str:
    try:
        from .._version import __version__

        return str(__version__)
    except ImportError:  # the binding is not built: the format does not depend on it
        return "unknown"


def _pyarrow() -> None:
    try:
        import pyarrow  # noqa: F401
        import pyarrow.parquet  # noqa: F401
    except ImportError as e:
        raise ImportError(f"sharded frames are Parquet files and need pyarrow (pip install pyarrow): {e}") from None


# ---------------------------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------------------------


def is_sharded(path: Any) -> bool:
    """Whether ``path`` is a directory (then it must hold sharded frames to be read as frames)."""
    try:
        return os.path.isdir(as_path(path))
    except TypeError:
        return False


def read_manifest(directory: Any) -> ShardManifest:
    """The manifest of a directory of sharded frames; :class:`~dpgp.DataFormatError` naming
    the file if it is missing, unreadable or inconsistent, ``FileNotFoundError`` if there is no
    such directory."""
    path = os.path.realpath(as_path(directory))
    if not os.path.isdir(path):
        if not os.path.exists(path):
            raise FileNotFoundError(2, "no such directory of sharded frames", path)
        raise DataFormatError(f"{path} is a file, not a directory of sharded frames")
    mpath = os.path.join(path, MANIFEST)
    if not os.path.isfile(mpath):
        raise DataFormatError(
            f"{mpath} is missing: {path} is not a directory of sharded frames (Frames.to_parquet writes one)"
        )
    try:
        with open(mpath, "rb") as fh:
            doc = json.loads(fh.read())
    except (OSError, ValueError) as e:  # ValueError: bad JSON or bad UTF-8
        raise DataFormatError(f"{mpath}: not a readable manifest ({type(e).__name__}: {e})") from None
    return parse_manifest(doc, path, mpath)


def parse_manifest(doc: Any, directory: str, mpath: str) -> ShardManifest:
    """A manifest's JSON, checked field by field; :class:`~dpgp.DataFormatError` naming ``mpath``."""

    def bad(msg: str) -> DataFormatError:
        return DataFormatError(f"{mpath}: {msg}; the manifest of sharded frames is damaged")

    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise DataFormatError(f"{mpath}: not a manifest of dpgp sharded frames (no 'format': {FORMAT!r})")
    version = doc.get("version")
    if not _is_int(version) or version < 1:
        raise bad(f"version {version!r} is not a format version")
    if version > VERSION:
        raise DataFormatError(
            f"{mpath}: written by a newer dpgp (format version {version}; this one reads up to {VERSION}); "
            "upgrade dpgp to read it"
        )
    n_frames, n_points, entries = doc.get("n_frames"), doc.get("n_points"), doc.get("shards")
    if not (_is_int(n_frames) and n_frames >= 1 and _is_int(n_points) and n_points >= n_frames):
        raise bad(f"n_frames {n_frames!r} and n_points {n_points!r} must be whole numbers, n_points >= n_frames >= 1")
    if not isinstance(entries, list) or not entries:
        raise bad("'shards' must be a non-empty list")
    shards = []
    stop = 0
    for i, e in enumerate(entries):
        if not isinstance(e, dict):
            raise bad(f"shard {i} is not an object")
        file, rng, points, cont = e.get("file"), e.get("frames"), e.get("points"), e.get("continues")
        if not isinstance(file, str) or file in ("", ".", "..") or os.path.basename(file) != file or "/" in file:
            raise bad(f"shard {i}'s file {file!r} is not a file name in the directory")
        if not (isinstance(rng, list) and len(rng) == 2 and all(_is_int(r) for r in rng)):
            raise bad(f"shard {i}'s frames {rng!r} are not a range [start, stop]")
        if rng[0] != stop or rng[1] <= rng[0]:
            raise bad(f"shard {i}'s frames {rng} do not follow on from frame {stop} (shards hold contiguous ranges)")
        if not _is_int(points) or points < rng[1] - rng[0]:
            raise bad(f"shard {i}'s points {points!r} are fewer than its frames")
        if cont is not None and not isinstance(cont, bool):
            raise bad(f"shard {i}'s continues {cont!r} is not true, false or null")
        stop = rng[1]
        shards.append(ShardInfo(file, rng[0], rng[1], points, cont))
    if stop != n_frames or sum(s.points for s in shards) != n_points:
        raise bad(
            f"the shards hold {stop} frames and {sum(s.points for s in shards)} points, not {n_frames} and {n_points}"
        )
    if len({s.file for s in shards}) != len(shards):
        raise bad("two shards name the same file")
    ids = _check_spec(doc.get("ids"), "ids", pair=True, bad=bad)
    labels = None if doc.get("labels") is None else _check_spec(doc.get("labels"), "labels", pair=False, bad=bad)
    tracks, units = doc.get("tracks"), doc.get("units")
    if not isinstance(tracks, bool):
        raise bad(f"'tracks' {tracks!r} is not true or false")
    if units is not None and not isinstance(units, str):
        raise bad(f"'units' {units!r} is not a string or null")
    summary = None
    if doc.get("summary") is not None:
        if not isinstance(doc["summary"], dict):
            raise bad("'summary' is not an object")
        try:
            summary = FramingSummary.from_dict(doc["summary"])
        except (TypeError, ValueError) as e:
            raise bad(f"'summary' is not a framing summary ({e})") from None
    order = doc.get("time_order")
    dt: float | None = None
    in_order, n_seq = False, None
    if order is not None:
        if not isinstance(order, dict):
            raise bad("'time_order' is not an object")
        step, sorted_, runs = order.get("dt"), order.get("in_time_order"), order.get("n_sequences")
        if not (isinstance(step, (int, float)) and not isinstance(step, bool) and np.isfinite(step) and step > 0):
            raise bad(f"'time_order' has dt {step!r}, not a positive number of seconds")
        if not (isinstance(sorted_, bool) and _is_int(runs) and 1 <= runs <= n_frames):
            raise bad(f"'time_order' {order!r} needs in_time_order (true or false) and n_sequences")
        dt, in_order, n_seq = float(step), sorted_, runs
    previous = doc.get("previous")
    min_speed = None
    if previous is not None:
        m = previous.get("heading_min_speed") if isinstance(previous, dict) else None
        if not (isinstance(m, (int, float)) and not isinstance(m, bool) and np.isfinite(m) and m >= 0):
            raise bad(f"'previous' {previous!r} needs heading_min_speed, a number of m/s >= 0")
        min_speed = float(m)
    return ShardManifest(
        directory=directory,
        version=version,
        n_frames=n_frames,
        n_points=n_points,
        shards=tuple(shards),
        ids=ids,
        labels=labels,
        tracks=tracks,
        units=units,
        summary=summary,
        dt=dt,
        in_time_order=in_order,
        n_sequences=n_seq,
        heading_min_speed=min_speed,
    )


def _is_int(x: Any) -> TypeGuard[int]:
    return isinstance(x, int) and not isinstance(x, bool)


def _check_spec(spec: Any, what: str, pair: bool, bad: Any) -> dict[str, Any]:
    kinds = ("array", "object", "pair") if pair else ("array", "object")
    if not isinstance(spec, dict) or spec.get("kind") not in kinds:
        raise bad(f"'{what}' {spec!r} must be an object with a kind of {kinds}")
    if spec["kind"] == "array":
        try:
            dtype = np.dtype(spec.get("dtype"))
        except (TypeError, ValueError):
            dtype = None
        if dtype is None or dtype.kind not in _ARRAY_KINDS:
            raise bad(f"'{what}' has the dtype {spec.get('dtype')!r}, not one of numbers, strings or times")
    return spec


def read_parts(manifest: ShardManifest, i: Any) -> StoredFrames:
    """The arrays of shard ``i`` (offsets from 0; its first frame is ``manifest.shards[i].start``).
    :class:`~dpgp.DataFormatError` naming the file if it is missing, unreadable, or does not
    hold what the manifest says."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    n = manifest.n_shards
    if isinstance(i, (bool, np.bool_)) or not isinstance(i, (int, np.integer)):
        raise InvalidInputError(f"a shard is named by its number (0 to {n - 1}), got {i!r}")
    if not 0 <= i < n:
        raise InvalidInputError(f"shard {i} is out of range: {manifest.directory} holds {n} shards (0 to {n - 1})")
    info = manifest.shards[int(i)]
    file = manifest.path(int(i))
    if not os.path.isfile(file):
        raise DataFormatError(
            f"{file}: shard {i} of {n} is missing; the sharded frames in {manifest.directory} are incomplete"
        )
    try:
        table = pq.read_table(file)
    except Exception as e:  # noqa: BLE001 - pyarrow raises its own types for a damaged file
        raise DataFormatError(f"{file}: shard {i} is not a readable Parquet file ({type(e).__name__}: {e})") from None

    def bad(msg: str) -> DataFormatError:
        return DataFormatError(f"{file}: {msg}; the shard is damaged or belongs to another write")

    try:
        meta = json.loads((table.schema.metadata or {}).get(_META_KEY, b"null"))
    except ValueError:
        meta = None
    want = {"shard": int(i), "n_shards": n, "frames": [info.start, info.stop], "points": info.points}
    if not isinstance(meta, dict) or meta.get("format") != FORMAT or {k: meta.get(k) for k in want} != want:
        got = {k: meta.get(k) for k in want} if isinstance(meta, dict) else meta
        raise bad(f"its own record {got} is not the manifest's {want}")
    needed = ["frame_number", "frame", *_FLOATS]
    needed += ["scene"] if manifest.ids["kind"] == "pair" else []
    needed += ["track"] if manifest.tracks else []
    needed += ["label"] if manifest.labels is not None else []
    needed += list(_PREVIOUS) if manifest.heading_min_speed is not None else []
    missing = [c for c in needed if c not in table.column_names]
    if missing:
        raise bad(f"it has no column(s) {missing}")
    if table.num_rows != info.points:
        raise bad(f"it holds {table.num_rows} rows, not the manifest's {info.points}")
    for c in needed:
        if table.column(c).null_count:
            raise bad(f"column {c!r} has {table.column(c).null_count} missing value(s)")
    number = table.column("frame_number").to_numpy()
    step = np.diff(number) if number.dtype.kind in "iu" else None
    if step is None or number[0] != info.start or number[-1] != info.stop - 1 or not np.all((step == 0) | (step == 1)):
        raise bad(f"its frame_number column does not run through frames {info.start} to {info.stop - 1} in order")
    first = np.flatnonzero(np.r_[True, step != 0])
    offsets = np.r_[first, len(number)].astype(np.int64)
    cols = {}
    for c in _FLOATS:
        col = table.column(c).to_numpy()
        if col.dtype != np.float64:
            raise bad(f"column {c!r} holds {col.dtype}, not float64")
        if not np.isfinite(col).all():
            raise bad(f"column {c!r} holds {int((~np.isfinite(col)).sum())} NaN or infinite value(s)")
        cols[c] = col
    xy = np.column_stack([cols["x"], cols["y"]])
    v = np.column_stack([cols["vx"], cols["vy"]])
    del cols
    tracks = None
    if manifest.tracks:
        tracks = table.column("track").to_numpy()
        if tracks.dtype.kind not in "iu":
            raise bad(f"column 'track' holds {tracks.dtype}, not whole numbers")
        tracks = np.array(tracks, dtype=np.int64)
    prev_v = prev_h = None
    if manifest.heading_min_speed is not None:
        pv = [table.column(c).to_numpy() for c in _PREVIOUS]
        if any(c.dtype != np.float64 for c in pv):
            raise bad(f"columns {list(_PREVIOUS)} hold {[str(c.dtype) for c in pv]}, not float64")
        if np.isinf(np.column_stack(pv)).any() or (np.isnan(pv[0]) != np.isnan(pv[1])).any():
            raise bad("its previous velocities hold inf, or NaN in one entry of a row only")
        prev_v, prev_h = np.column_stack(pv[:2]), np.array(pv[2])
    try:
        ids = _per_frame(manifest.ids, table, "frame", first)
        labels = None if manifest.labels is None else _per_frame(manifest.labels, table, "label", first)
    except (pa.ArrowException, TypeError, ValueError) as e:
        raise bad(f"its ids or labels do not read as the manifest says ({e})") from None
    return StoredFrames(
        ids, offsets, xy, v, labels, tracks, manifest.summary, prev_v, prev_h, manifest.heading_min_speed
    )


def _per_frame(spec: dict[str, Any], table: Any, name: str, first: np.ndarray) -> np.ndarray:
    """A per-frame column (one value per frame, read at each frame's first row)."""
    values = table.column(name).take(first).to_numpy(zero_copy_only=False)
    if spec["kind"] == "array":
        return np.array(values, dtype=np.dtype(spec["dtype"]))
    out = np.empty(len(first), dtype=object)
    if spec["kind"] == "pair":
        scenes = table.column("scene").take(first).to_numpy(zero_copy_only=False)
        out[:] = list(zip(scenes.tolist(), values.tolist()))
    else:
        out[:] = values.tolist()
    return out


def read_all(directory: Any) -> StoredFrames:
    """Every shard of a directory, as the arrays of one :class:`~dpgp.Frames`. Positions,
    velocities and track ids go straight into arrays of the full size, shard by shard, so that
    no second copy of all frames is ever held."""
    _pyarrow()
    manifest = read_manifest(directory)
    xy = np.empty((manifest.n_points, 2))
    v = np.empty((manifest.n_points, 2))
    tracks: np.ndarray | None = np.empty(manifest.n_points, dtype=np.int64) if manifest.tracks else None
    has_prev = manifest.heading_min_speed is not None
    prev_v = np.empty((manifest.n_points, 2)) if has_prev else None
    prev_h = np.empty(manifest.n_points) if has_prev else None
    offsets = np.empty(manifest.n_frames + 1, dtype=np.int64)
    offsets[0] = 0
    ids: list[np.ndarray] = []
    labels: list[np.ndarray] = []
    for i, info in enumerate(manifest.shards):
        part = read_parts(manifest, i)
        r0 = int(offsets[info.start])
        xy[r0 : r0 + info.points] = part.xy
        v[r0 : r0 + info.points] = part.v
        if tracks is not None and part.tracks is not None:
            tracks[r0 : r0 + info.points] = part.tracks
        if prev_v is not None and prev_h is not None and part.prev_v is not None and part.prev_heading is not None:
            prev_v[r0 : r0 + info.points] = part.prev_v
            prev_h[r0 : r0 + info.points] = part.prev_heading
        offsets[info.start + 1 : info.stop + 1] = part.offsets[1:] + r0
        ids.append(part.ids)
        if part.labels is not None:
            labels.append(part.labels)
    return StoredFrames(
        np.concatenate(ids),
        offsets,
        xy,
        v,
        np.concatenate(labels) if manifest.labels is not None else None,
        tracks,
        manifest.summary,
        prev_v,
        prev_h,
        manifest.heading_min_speed,
    )
