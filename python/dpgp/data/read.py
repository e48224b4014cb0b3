"""Reading any supported traffic file into frames: the format is recognised by the file's own
column names (:func:`detect_format`), then read (:func:`read`). What ``dpgp fit`` and ``dpgp
evaluate`` do with ``--format auto``.

Formats and what recognises them (names compared without case):

=============  ==================================================================================
format         recognised by
=============  ==================================================================================
``sumo``       an ``.xml``/``.xml.gz`` file (FCD output), or ``timestep_time`` (SUMO's xml2csv)
``ngsim``      ``Vehicle_ID, Frame_ID, Local_X, Local_Y``
``interaction``  ``track_id, frame_id, timestamp_ms, x, y`` (INTERACTION recorded tracks)
``highd``      ``id, frame, x, y, xVelocity, yVelocity``
``ind``        ``trackId, frame, xCenter, yCenter`` (inD, rounD, exiD)
``eth_ucy``    no header, four numbers a row (``frame ped_id x y``)
``frames``     a frame column (``frame``, ``frame_id``, ...) and no track id (``x, y, vx, vy`` besides),
               or a directory of sharded frames (``Frames.to_parquet``)
``tracks``     a track id (``track_id``, ``id``, ``vehicle_id``, ...), ``t`` or ``time``, ``x``, ``y``
=============  ==================================================================================

The specific formats are tried first, in this order, then the generic ``frames`` and ``tracks``;
a file none of them recognises is a :class:`~dpgp.DataFormatError` naming the formats and the
columns it has.
"""

from __future__ import annotations

import os
import re
from typing import TYPE_CHECKING, Any

from .._arrays import as_path
from .._constants import DEFAULT_DT
from ..exceptions import DataFormatError, InvalidInputError
from .frames import Frames, read_frames
from .framing import FramingSummary, make_frames
from .tracks import _AUTO, _PRESET_ALIASES, _PRESETS, _first_line, _is_number, read_ngsim, read_tracks

if TYPE_CHECKING:
    import pandas as pd

#: Every format :func:`read` takes (``"auto"`` recognises them).
FORMATS = ("frames", "tracks", "ngsim", *_PRESETS)

_FRAME_IDS = {"frame", "frame_idx", "frame_id", "frameid", "frame_index"}
_TRACK_IDS = set(_AUTO["id"])
#: Specific formats by the columns each always has (lower case), tried in this order.
_SIGNATURES: tuple[tuple[str, frozenset[str]], ...] = (
    ("sumo", frozenset({"timestep_time"})),
    ("ngsim", frozenset({"vehicle_id", "frame_id", "local_x", "local_y"})),
    ("interaction", frozenset({"track_id", "frame_id", "timestamp_ms", "x", "y"})),
    ("highd", frozenset({"id", "frame", "x", "y", "xvelocity", "yvelocity"})),
    ("ind", frozenset({"trackid", "frame", "xcenter", "ycenter"})),
)


def columns_of(path: str | os.PathLike) -> list[str] | None:
    """The column names of a table file, read from its header (Parquet: its schema); None for
    a text file without a header (its first row is all numbers)."""
    path = as_path(path)
    if path.lower().endswith((".parquet", ".pq")):
        try:
            import pyarrow.parquet as pq

            return [str(c) for c in pq.read_schema(path).names]
        except ImportError as e:
            raise ImportError(f"reading Parquet needs pyarrow (pip install pyarrow): {e}") from None
        except Exception as e:  # noqa: BLE001 - pyarrow raises its own types for a file that is not Parquet
            raise DataFormatError(f"{path} is not a readable Parquet file: {e}") from None
    first = _first_line(path)
    if "\x00" in first:
        raise DataFormatError(f"{path} is a binary file, not a text table (Parquet files must end in .parquet)")
    sep = next((s for s in ("\t", ";", ",") if s in first), r"\s+")
    tokens = [tok.strip().strip('"') for tok in re.split(sep, first.strip())]
    if all(_is_number(tok) for tok in tokens if tok):
        return None
    return tokens


def detect_format(path: str | os.PathLike) -> str:
    """The format of a traffic file, one of :data:`FORMATS`, recognised by its name (SUMO's
    ``.xml``) and its own column names (the table in this module's docstring).
    :class:`~dpgp.DataFormatError` naming the formats and the columns seen if none fits."""
    path = as_path(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"no such file: {path}")
    if os.path.isdir(path):
        return "frames"  # sharded frames (Frames.to_parquet); read_frames names what is missing
    if path.lower().endswith((".xml", ".xml.gz")):
        return "sumo"
    cols = columns_of(path)
    if cols is None:
        n = len(_first_line(path).split())
        if n == 4:
            return "eth_ucy"
        raise DataFormatError(
            f"{path}: no header and {n} numbers a row; of the formats without a header dpgp knows only eth_ucy "
            f"(frame ped_id x y). Add a header, or read it with dpgp.read_tracks(path, id=..., t=..., x=..., y=...)"
        )
    names = {c.strip().lower() for c in cols}
    for fmt, required in _SIGNATURES:
        if required <= names:
            return fmt
    if names & _FRAME_IDS and not names & _TRACK_IDS:
        return "frames"
    if names & _TRACK_IDS and names & set(_AUTO["t"]) and {"x", "y"} <= names:
        return "tracks"
    raise DataFormatError(
        f"{path}: columns {cols} match no format dpgp reads. Formats and the columns that identify them: "
        + "; ".join(f"{fmt}: {', '.join(sorted(req))}" for fmt, req in _SIGNATURES)
        + "; eth_ucy: no header, frame ped_id x y; frames: frame, x, y, vx, vy; tracks: track_id (or id, ...), "
        "t (or time), x, y. Rename the columns, or pass format= (dpgp fit --format) and the column names"
    )


def _format(path: str, format: str) -> str:
    if format == "auto":
        return detect_format(path)
    fmt = _PRESET_ALIASES.get(str(format).lower(), str(format).lower())
    if fmt not in FORMATS:
        raise InvalidInputError(f"unknown format {format!r}; choose 'auto' or one of {FORMATS}")
    return fmt


def read_trajectories(path: str | os.PathLike, format: str = "auto") -> pd.DataFrame:
    """The tracks table (:func:`dpgp.read_tracks`) of a trajectory file in any supported format;
    :class:`~dpgp.DataFormatError` for a file of frames, which holds no tracks."""
    path = as_path(path)
    fmt = _format(path, format)
    if fmt == "frames":
        raise DataFormatError(f"{path} holds frames (frame, x, y, vx, vy), not trajectories")
    if fmt == "ngsim":
        return read_ngsim(path)
    return read_tracks(path, preset=None if fmt == "tracks" else fmt)


def read(
    path: str | os.PathLike,
    format: str = "auto",
    *,
    roi: Any = None,
    dt: float | None = None,
    units: str | None = None,
) -> Frames:
    """Frames ready to fit from a traffic file of any supported format (:data:`FORMATS`;
    ``"auto"`` recognises it by its columns, see :func:`detect_format`).

    Trajectories are framed by :func:`dpgp.make_frames` every ``dt`` seconds (default
    :data:`~dpgp._constants.DEFAULT_DT`, 0.5 s) inside ``roi``, converted by ``units``. A file
    of frames is read as it is, cropped to ``roi`` (:meth:`Frames.crop`); ``roi`` and ``dt`` are
    then recorded in its summary, so that simulations and plots of a model default to them."""
    path = as_path(path)
    fmt = _format(path, format)
    if fmt != "frames":
        tracks = read_trajectories(path, fmt)
        return make_frames(tracks, roi=roi, dt=DEFAULT_DT if dt is None else dt, units=units)
    if units is not None:
        raise InvalidInputError("units applies to trajectories that are framed here, not to a file of frames")
    frames = read_frames(path)
    if roi is None and dt is None:
        return frames
    n_read = len(frames)
    if roi is not None:
        frames = frames.crop(roi)
        roi = tuple(float(v) for v in roi)
    frames.summary = FramingSummary(
        dt=DEFAULT_DT if dt is None else float(dt), max_gap=0.0, roi=roi,
        units=None, velocity="columns", smoothing=None, n_rows=frames.n_points, n_tracks=0, n_segments=0,
        n_gaps=0, n_gap_times=0, n_segments_between_grid_times=0, n_rows_between_grid_times=0,
        n_single_sample_segments=0, n_unsmoothed_segments=0, n_resampled=frames.n_points, n_outside_roi=0,
        n_points=frames.n_points, n_frames=len(frames), n_empty_frames=n_read - len(frames), n_scenes=1,
    )  # fmt: skip
    return frames


__all__ = ["FORMATS", "columns_of", "detect_format", "read", "read_trajectories"]
