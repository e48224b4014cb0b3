"""Readers that turn raw trajectory files into a *tracks table*.

A tracks table is a pandas DataFrame with one row per observation of one moving agent:

``track``  int64, the trip (0, 1, ... in order of the source's id, then start time);
``t``      float64, time in seconds;
``x, y``   float64, position in the source's units (NGSIM: feet; the others: metres);
``vx, vy`` float64, the velocity *vector*, only where the source gives one;
``scene``  only where the source holds independent recordings (INTERACTION ``case_id``,
           a multi-site NGSIM export): frames are then built per scene;

followed by the source's other columns (its id and time columns among them). Rows are sorted
by ``track`` then ``t``, and time strictly increases inside a track. What a reader had to
drop or split is reported in ``table.attrs["dpgp"]``.
"""

from __future__ import annotations

import difflib
import gzip
import math
import os
import re
from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from .._arrays import as_path, column_floats, is_path
from ..exceptions import DataFormatError, InvalidInputError

if TYPE_CHECKING:
    import pandas as pd

# ---------------------------------------------------------------------------------------------
# NGSIM
# ---------------------------------------------------------------------------------------------

NGSIM_FRAME_SECONDS = 0.1  # NGSIM video is transcribed at 10 frames per second

# The published CSV export's 25 columns; other spellings are renamed to these.
_NGSIM_CSV = (
    "Vehicle_ID Frame_ID Total_Frames Global_Time Local_X Local_Y Global_X Global_Y v_length "
    "v_Width v_Class v_Vel v_Acc Lane_ID O_Zone D_Zone Int_ID Section_ID Direction Movement "
    "Preceding Following Space_Headway Time_Headway Location"
).split()
# Headerless .txt files of the original releases, told apart by their number of columns.
_NGSIM_TXT = {
    18: _NGSIM_CSV[:14] + ["Preceding", "Following", "Space_Headway", "Time_Headway"],  # US-101, I-80
    24: _NGSIM_CSV[:24],  # Lankershim, Peachtree
    25: _NGSIM_CSV,
}
_NGSIM_VARIANTS = {
    "v_length": "v_length",
    "space_hdwy": "Space_Headway",
    "time_hdwy": "Time_Headway",
    "origin_zone": "O_Zone",
    "destination_zone": "D_Zone",
}


def read_ngsim(path: str | os.PathLike, *, split_gap: float = 1.0) -> pd.DataFrame:
    """Read a raw NGSIM trajectory file (US-101, I-80, Lankershim, Peachtree) as a tracks table.

    Parameters
    ----------
    path
        The CSV export (comma-separated, with header) or an original whitespace-separated
        ``.txt`` file (with or without header; 18 columns for US-101/I-80, 24 for Lankershim
        and Peachtree). ``.gz`` works too.
    split_gap
        Seconds: a vehicle's trip is cut into separate tracks where its ``Frame_ID`` jumps by
        more than this. NGSIM reuses ``Vehicle_ID`` for unrelated trips.

    Returns
    -------
    DataFrame
        ``track, t, x, y`` then the source columns (column-name variants renamed to the CSV
        export's spelling: ``v_length``, ``Space_Headway``, ``Time_Headway``, ``O_Zone``,
        ``D_Zone``). ``t = Frame_ID * 0.1`` s (``Global_Time`` is not a usable clock);
        ``x, y = Local_X, Local_Y`` in feet. There is no ``vx, vy``: NGSIM's ``v_Vel`` is a
        *speed* along the path, not a vector, so it is kept as a source column and
        :func:`dpgp.make_frames` derives velocity vectors from positions.

    Notes
    -----
    A trip is identified by ``Vehicle_ID`` and ``Total_Frames`` (and ``Location`` when a file
    holds several sites: they become ``scene``), because the same ``Vehicle_ID`` appears in
    overlapping frames for unrelated vehicles. Rows repeated exactly are dropped; conflicting
    rows for one trip at one frame raise :class:`DataFormatError`. Counts are in
    ``table.attrs["dpgp"]``.
    """
    import pandas as pd

    _check_positive("split_gap", split_gap)
    path = _existing(path)
    first = _first_line(path)
    comma = "," in first
    tokens = [tok for tok in re.split(r"[,\s]+", first.strip()) if tok]
    header = 0 if tokens and not _is_number(tokens[0].strip('"')) else None
    try:
        df = pd.read_csv(
            path,
            sep="," if comma else r"\s+",
            header=header,
            thousands="," if comma else None,
            encoding="utf-8-sig",
            skipinitialspace=True,
            low_memory=False,
        )
    except _damaged_file_errors() as e:
        raise DataFormatError(f"{path} is not a readable NGSIM file ({type(e).__name__}: {e})") from None
    df = _name_ngsim_columns(df, path, header is None)
    missing = [c for c in ("Vehicle_ID", "Frame_ID", "Local_X", "Local_Y") if c not in df.columns]
    if missing:
        raise DataFormatError(
            f"{path} is not an NGSIM trajectory file: no column {missing} (found {list(df.columns)}); "
            "for other tables use dpgp.read_tracks"
        )
    if len(df) == 0:
        raise DataFormatError(f"{path} has a header but no rows of data")
    for col in ("Vehicle_ID", "Frame_ID", "Total_Frames", "Local_X", "Local_Y"):
        if col in df.columns:
            df[col] = _numeric(df[col], col, path)
    report: dict[str, Any] = {}
    n_read = len(df)
    df = df.drop_duplicates(ignore_index=True)
    report["exact_duplicate_rows_dropped"] = n_read - len(df)

    key = ["Vehicle_ID"] + [c for c in ("Total_Frames", "Location") if c in df.columns]
    multi_site = "Location" in df.columns and df["Location"].nunique() > 1
    df = df.sort_values(key + ["Frame_ID"], kind="stable", ignore_index=True)
    k = df.groupby(key, sort=False, dropna=False).ngroup().to_numpy()
    frame = df["Frame_ID"].to_numpy(dtype=np.float64)
    same = k[1:] == k[:-1]
    step = np.diff(frame)
    clash = same & (step == 0)
    if clash.any():
        i = int(np.flatnonzero(clash)[0])
        raise DataFormatError(
            f"{path}: {int(clash.sum())} pair(s) of different rows for the same vehicle trip at the same "
            f"frame, first Vehicle_ID {df['Vehicle_ID'].iat[i]} at Frame_ID {frame[i]:.0f}; "
            "remove the conflicting rows (a file that joins several recordings, such as the three "
            "US-101 periods, must be split into one file per recording first)"
        )
    jump = same & (step * NGSIM_FRAME_SECONDS > split_gap)
    report["trips_split_at_time_jumps"] = int(jump.sum())
    track = np.cumsum(np.r_[True, ~same | jump]) - 1
    per_id = pd.Series(track).groupby(df["Vehicle_ID"].to_numpy()).nunique()
    report["vehicle_ids_with_several_tracks"] = int((per_id > 1).sum())

    clash = [c for c in ("track", "t", "x", "y", "scene") if c in df.columns]
    if clash:  # not NGSIM columns: a renamed or foreign header field
        raise DataFormatError(f"{path}: column(s) {clash} clash with the tracks table's own columns; rename them")
    out = df.drop(columns=["Local_X", "Local_Y"])
    out.insert(0, "track", track.astype(np.int64))
    out.insert(1, "t", frame * NGSIM_FRAME_SECONDS)
    out.insert(2, "x", df["Local_X"].to_numpy(dtype=np.float64))
    out.insert(3, "y", df["Local_Y"].to_numpy(dtype=np.float64))
    if multi_site:
        out.insert(4, "scene", df["Location"].to_numpy())
    _check_finite_columns(out, ("x", "y", "t"), str(path))
    out.attrs["dpgp"] = {"source": str(path), "format": "ngsim", "units": "ft", "report": report}
    return out


def _name_ngsim_columns(df: pd.DataFrame, path: Any, headerless: bool) -> pd.DataFrame:
    """``df`` (all of an NGSIM file, or a chunk of it) with the standard column names: by column
    count for a text file without a header, else its header's names normalised."""
    if not headerless:
        return df.rename(columns=_ngsim_names(df.columns))
    names = _NGSIM_TXT.get(df.shape[1])
    if names is None:
        raise DataFormatError(
            f"{path} has no header and {df.shape[1]} columns; NGSIM text files have 18 "
            "(US-101, I-80), 24 (Lankershim, Peachtree) or 25 (CSV export) columns"
        )
    df.columns = names
    return df


def _ngsim_names(columns: Sequence[object]) -> dict[object, str]:
    canon = {c.lower(): c for c in _NGSIM_CSV}
    canon.update(_NGSIM_VARIANTS)
    return {c: canon[str(c).strip().lower()] for c in columns if str(c).strip().lower() in canon}


# ---------------------------------------------------------------------------------------------
# Generic tables and presets
# ---------------------------------------------------------------------------------------------

# Each preset names the columns of a public format; explicit arguments override it.
_PRESETS: dict[str, dict[str, Any]] = {
    # ETH/UCY: "frame ped_id x y", no header; frame numbers count 25 Hz video frames and step by
    # 10 between annotations, i.e. 0.4 s.
    "eth_ucy": dict(
        names=["frame", "ped_id", "x", "y"], id="ped_id", t="frame", x="x", y="y", time_scale=0.04, units="m"
    ),
    # INTERACTION: track_id restarts in every case_id (an independent scene) and so does time.
    "interaction": dict(
        id="track_id", t="timestamp_ms", x="x", y="y", vx="vx", vy="vy", time_scale=1e-3, scene="case_id", units="m"
    ),
    # highD: 25 Hz; x, y are the bounding box's upper-left corner, y points down (image axes).
    "highd": dict(id="id", t="frame", x="x", y="y", vx="xVelocity", vy="yVelocity", time_scale=1 / 25, units="m"),
    # inD (also rounD, exiD): 25 Hz, centre positions.
    "ind": dict(
        id="trackId",
        t="frame",
        x="xCenter",
        y="yCenter",
        vx="xVelocity",
        vy="yVelocity",
        time_scale=1 / 25,
        scene="recordingId",
        units="m",
    ),
    # SUMO floating-car data (XML or xml2csv's CSV), handled by _read_sumo.
    "sumo": dict(id=["kind", "id"], t="time", x="x", y="y", vx="vx", vy="vy", time_scale=1.0, units="m"),
}
_PRESET_ALIASES = {"eth": "eth_ucy", "ucy": "eth_ucy", "round": "ind", "exid": "ind", "fcd": "sumo"}

# Column names found without being told (case-insensitive), when no preset is given.
_AUTO = {
    "id": ("track", "track_id", "id", "trackid", "vehicle_id", "agent_id", "object_id", "ped_id"),
    "t": ("t", "time"),
    "x": ("x",),
    "y": ("y",),
    "vx": ("vx", "xvelocity", "vel_x", "v_x"),
    "vy": ("vy", "yvelocity", "vel_y", "v_y"),
}


def read_tracks(
    source: str | os.PathLike | Any,
    id: str | int | Sequence[str | int] | None = None,
    t: str | int | None = None,
    x: str | int | None = None,
    y: str | int | None = None,
    vx: str | int | None = None,
    vy: str | int | None = None,
    preset: str | None = None,
    *,
    scene: str | int | None = None,
    time_scale: float | None = None,
    sort: bool = False,
) -> pd.DataFrame:
    """Read any trajectory table into a tracks table (see the module docstring for its columns).

    Parameters
    ----------
    source
        A CSV / TSV / semicolon- or whitespace-separated text file (``.gz`` works), a Parquet
        file (needs pyarrow), a SUMO FCD ``.xml`` file, or a pandas or polars DataFrame.
    id, t, x, y, vx, vy
        Column names (or positions, for a file without header). ``id`` may be a list of
        columns that together identify a track. Unnamed ones are looked up among common names
        (``track``/``id``/``track_id``..., ``t``/``time``, ``x``, ``y``, ``vx``/``xVelocity``...).
        Velocity columns are optional; without them :func:`dpgp.make_frames` differences
        positions.
    preset
        ``"eth_ucy"`` (``frame ped_id x y``, no header, frame × 0.04 s), ``"interaction"``
        (``timestamp_ms``, one scene per ``case_id``), ``"highd"`` (``frame`` at 25 Hz,
        ``xVelocity``...), ``"ind"`` (inD/rounD/exiD: ``trackId``, ``xCenter``...), or
        ``"sumo"`` (FCD output, XML or the CSV of SUMO's ``xml2csv``; ``vx, vy`` from
        ``speed`` and ``angle``, degrees clockwise from north). ``"ngsim"`` calls
        :func:`read_ngsim`.
    scene
        Column holding independent recordings; frames are then built per scene.
    time_scale
        Seconds per unit of the ``t`` column (``1e-3`` for milliseconds, ``1/25`` for frame
        numbers at 25 Hz). Default 1, or the preset's.
    sort
        Put rows of each track in time order. Left False, rows whose time goes backwards inside
        a track raise :class:`InvalidInputError` (a clock reset or mixed-up ids); set True when
        the file is merely unsorted.
    """
    import pandas as pd

    if preset is not None:
        preset = _PRESET_ALIASES.get(str(preset).lower(), str(preset).lower())
        if preset == "ngsim":
            if not is_path(source):
                raise InvalidInputError("preset='ngsim' reads a file; pass its path")
            return read_ngsim(source)
        if preset not in _PRESETS:
            raise InvalidInputError(f"unknown preset {preset!r}; choose one of {sorted(_PRESETS) + ['ngsim']}")
    spec = dict(_PRESETS.get(preset or "", {}))
    where = as_path(source) if is_path(source) else type(source).__name__

    if preset == "sumo":
        df = _read_sumo(source)
    elif is_path(source):
        path = _existing(source)
        if path.lower().endswith((".xml", ".xml.gz")):
            df = _read_sumo(path)
            preset, spec = "sumo", dict(_PRESETS["sumo"])
        else:
            df = _read_table(path, spec.get("names"))
    elif isinstance(source, pd.DataFrame):
        df = source
    elif hasattr(source, "columns") and hasattr(source, "to_numpy"):  # polars, without pyarrow
        df = pd.DataFrame({c: source[c].to_numpy() for c in source.columns})  # type: ignore[index, union-attr]
    else:
        raise DataFormatError(f"read_tracks takes a path or a DataFrame, got {type(source).__name__}")
    if spec.get("names") and list(df.columns) == list(range(len(spec["names"]))):
        df = df.set_axis(spec["names"], axis=1)

    given = {"id": id, "t": t, "x": x, "y": y, "vx": vx, "vy": vy, "scene": scene}
    if preset == "interaction" and id is None and "case_id" in df.columns:
        spec["id"] = ["case_id", "track_id"]  # track ids restart in every case
    cols = _resolve_columns(df, given, spec, where, use_auto=preset is None)
    _check_unique_columns(df, cols, where)
    scale = spec.get("time_scale", 1.0) if time_scale is None else time_scale
    _check_positive("time_scale", scale)
    out = _build_tracks(df, cols, float(scale), sort, where)
    out.attrs["dpgp"] = {
        "source": where,
        "format": preset or "table",
        "units": spec.get("units"),
        "report": out.attrs.get("dpgp_report", {}),
    }
    out.attrs.pop("dpgp_report", None)
    return out


def _resolve_columns(
    df: pd.DataFrame, given: dict[str, Any], spec: dict[str, Any], where: str, use_auto: bool
) -> dict[str, Any]:
    """Map each role (id, t, x, y, vx, vy, scene) to column(s) of ``df``; raise on a bad name."""
    columns = list(df.columns)
    lower = {str(c).strip().lower(): c for c in columns}
    found: dict[str, Any] = {}
    for role in ("id", "t", "x", "y", "vx", "vy", "scene"):
        name = given.get(role)
        optional = role in ("vx", "vy", "scene")
        if name is None:
            name = spec.get(role)
            if name is None and use_auto and role in _AUTO:
                name = next((lower[a] for a in _AUTO[role] if a in lower), None)
            if name is None or (optional and not _has_all(columns, name)):
                if not optional:
                    raise DataFormatError(
                        f"{where}: no column for {role!r} (expected one of {list(_AUTO[role])}, any case); "
                        f"the table has {columns}. Name it: read_tracks(..., {role}='your_column')"
                        + (" or choose a preset" if use_auto else "")
                        + _hint(lower)
                    )
                continue
        names = list(name) if isinstance(name, (list, tuple)) else [name]
        for n in names:
            if n not in columns:
                hint = difflib.get_close_matches(str(n), [str(c) for c in columns], n=1)
                raise DataFormatError(
                    f"{where}: column {n!r} (for {role}) is not in the table"
                    + (f"; did you mean {hint[0]!r}?" if hint else "")
                    + f" The table has {columns}"
                )
        found[role] = names if role == "id" else names[0]
    if ("vx" in found) != ("vy" in found):
        raise DataFormatError(f"{where}: give both velocity columns vx and vy, or neither (found only one)")
    return found


def _hint(lower: dict[str, Any]) -> str:
    """A pointer to the right reader for tables that are not generic tracks."""
    if {"vehicle_id", "frame_id", "local_x"} <= lower.keys():
        return ". This looks like an NGSIM file: read it with dpgp.read_ngsim"
    if {"x", "y"} <= lower.keys() and lower.keys() & {"frame", "frame_idx"} and not lower.keys() & set(_AUTO["id"]):
        return ". This looks like an already framed table (no track ids): read it with dpgp.read_frames"
    return ""


def _has_all(columns: list, name: Any) -> bool:
    names = list(name) if isinstance(name, (list, tuple)) else [name]
    return all(n in columns for n in names)


def _build_tracks(df: pd.DataFrame, cols: dict[str, Any], time_scale: float, sort: bool, where: str) -> pd.DataFrame:
    """The canonical table: numeric checks, track numbering, time order."""
    import pandas as pd

    values = {}
    for role in ("t", "x", "y", "vx", "vy"):
        if role in cols:
            values[role] = column_floats(_numeric(df[cols[role]], cols[role], where), cols[role], where)
    if time_scale != 1.0:
        values["t"] = values["t"] * time_scale
    for role, arr in values.items():
        bad = ~np.isfinite(arr)
        if bad.any():
            raise InvalidInputError(
                f"{where}: column {cols[role]!r} ({role}) has {int(bad.sum())} missing or infinite value(s), "
                f"first at row {int(np.flatnonzero(bad)[0])}; drop or fill those rows first"
            )
    if len(df) == 0:
        raise DataFormatError(f"{where}: the table has no rows")

    # Track numbers: 0.. in order of the id value(s), so that they do not depend on row order.
    id_cols = cols["id"]
    try:
        if len(id_cols) == 1:
            codes, _ = pd.factorize(df[id_cols[0]], sort=True, use_na_sentinel=False)
        else:
            codes = df.groupby(id_cols, sort=True, dropna=False).ngroup().to_numpy()
        codes = codes.astype(np.int64, copy=False)
        scene_codes = None
        if "scene" in cols and cols["scene"] not in id_cols:
            scene_codes, _ = pd.factorize(df[cols["scene"]], sort=True, use_na_sentinel=False)
    except TypeError as e:  # lists or a mix of types that cannot be ordered (numbers and None)
        named = id_cols + ([cols["scene"]] if "scene" in cols else [])
        raise DataFormatError(
            f"{where}: the id column(s) {named} hold values that cannot be compared ({e}); "
            "ids must be numbers or strings"
        ) from None
    if scene_codes is not None:
        # A track lives in one scene: make the scene part of its identity.
        combined = scene_codes.astype(np.int64) * (int(codes.max()) + 1) + codes
        codes = pd.factorize(combined, sort=True)[0].astype(np.int64, copy=False)

    t_arr = values["t"]
    if sort:
        order = np.lexsort((t_arr, codes))
    elif np.all(codes[1:] >= codes[:-1]):
        order = None  # already grouped by track in id order
    else:
        order = np.argsort(codes, kind="stable")  # keep each track's own row order
    c_sorted = codes if order is None else codes[order]
    t_sorted = t_arr if order is None else t_arr[order]
    same = c_sorted[1:] == c_sorted[:-1]
    step = np.diff(t_sorted)
    bad = same & (step <= 0)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        r0, r1 = (i, i + 1) if order is None else (int(order[i]), int(order[i + 1]))
        tid = [v.item() if isinstance(v, np.generic) else v for v in df[id_cols].iloc[r1].tolist()]
        what = "repeats" if step[i] == 0 else "goes backwards"
        fix = (
            "remove the duplicate rows"
            if step[i] == 0 or sort
            else "pass sort=True if the rows are merely unsorted, or fix the track ids"
        )
        raise InvalidInputError(
            f"{where}: time {what} inside track {tid[0] if len(tid) == 1 else tuple(tid)!r}: "
            f"row {r1} has t={t_sorted[i + 1]:g} s after row {r0} at t={t_sorted[i]:g} s (rows counted from 0) "
            f"({int(bad.sum())} such place(s)); {fix}"
        )

    # Keep the source's other columns; the ones copied into t, x, y, vx, vy go, except a
    # rescaled time column (frame numbers still mean something). Name clashes get "_source".
    used = {cols[r] for r in ("x", "y", "vx", "vy") if r in cols}
    if time_scale == 1.0:
        used.add(cols["t"])
    if cols.get("scene") == "scene":
        used.add("scene")
    if id_cols == ["track"] and np.array_equal(df["track"].to_numpy(), codes):
        used.add("track")  # already a tracks table: its numbering is unchanged
    rest = [c for c in df.columns if c not in used]
    body = df[rest] if order is None else df[rest].take(order)
    body = body.reset_index(drop=True)
    canon = ("track", "t", "x", "y", "vx", "vy", "scene")
    body = body.rename(columns={c: f"{c}_source" for c in rest if c in canon})
    head: dict[str, Any] = {"track": c_sorted}
    for role in ("t", "x", "y", "vx", "vy"):
        if role in values:
            head[role] = values[role] if order is None else values[role][order]
    if "scene" in cols:
        sc = df[cols["scene"]].to_numpy()
        head["scene"] = sc if order is None else sc[order]
    return pd.concat([pd.DataFrame(head), body], axis=1)


# ---------------------------------------------------------------------------------------------
# SUMO floating-car data
# ---------------------------------------------------------------------------------------------


def _read_sumo(source: Any) -> pd.DataFrame:
    """SUMO FCD output as a flat table ``time, kind, id, x, y, vx, vy, speed, angle, ...``."""
    import pandas as pd

    if is_path(source):
        path = _existing(source)
        if is_sumo_xml(path):
            df = _read_sumo_xml(path)
        else:
            df = _read_sumo_csv(_read_table(path, None), path)
    elif isinstance(source, pd.DataFrame):
        df = _read_sumo_csv(source, "DataFrame")
    else:
        raise DataFormatError(f"preset='sumo' takes a path or a DataFrame, got {type(source).__name__}")
    return sumo_velocity(df)


def is_sumo_xml(path: str) -> bool:
    """Whether a SUMO file is FCD XML (else the CSV of ``xml2csv``)."""
    return path.lower().endswith((".xml", ".xml.gz")) or _first_line(path).lstrip().startswith("<")


def sumo_velocity(df: pd.DataFrame) -> pd.DataFrame:
    """``vx, vy`` from SUMO's ``speed`` and ``angle`` (inserted after ``x, y``), when it has both."""
    if "speed" in df.columns and "angle" in df.columns:
        speed = _numeric(df["speed"], "speed", "SUMO").to_numpy(dtype=np.float64)
        heading = np.deg2rad(_numeric(df["angle"], "angle", "SUMO").to_numpy(dtype=np.float64))
        # SUMO's angle is the heading in degrees clockwise from north (+y): east is 90.
        df.insert(5, "vx", speed * np.sin(heading))
        df.insert(6, "vy", speed * np.cos(heading))
    return df


def _read_sumo_xml(path: str) -> pd.DataFrame:
    return next(sumo_xml_chunks(path, None))


def sumo_xml_chunks(path: str, rows: int | None) -> Iterator[pd.DataFrame]:
    """SUMO FCD XML as tables of up to ``rows`` rows each, in the file's order (``None``: one
    table of every row); the parser frees each timestep once read, so a chunk at a time is all
    that is held."""
    import xml.etree.ElementTree as ET

    buf: list[dict[str, Any]] = []
    time = math.nan
    n = 0
    opener = gzip.open if path.lower().endswith(".gz") else open
    try:
        with opener(path, "rb") as fh:
            events = ET.iterparse(fh, events=("start", "end"))
            _, root = next(events)
            if root.tag != "fcd-export":
                raise DataFormatError(
                    f"{path} is XML but not SUMO FCD output: root <{root.tag}>, expected <fcd-export>"
                )
            for event, elem in events:
                if event == "start":
                    if elem.tag == "timestep":
                        time = float(elem.get("time", "nan"))
                    continue
                if elem.tag in ("vehicle", "person", "container"):
                    row = dict(elem.attrib)
                    row["time"], row["kind"] = time, elem.tag
                    buf.append(row)
                elif elem.tag == "timestep":
                    root.clear()  # free what is parsed: FCD files run to gigabytes
                    if rows is not None and len(buf) >= rows:
                        n += len(buf)
                        yield _sumo_table(buf, path)
                        buf = []
    except DataFormatError:
        raise
    except ET.ParseError as e:
        raise DataFormatError(f"{path} is not well-formed XML: {e}") from None
    except _damaged_file_errors() as e:
        raise DataFormatError(f"{path} could not be read ({type(e).__name__}: {e}); is it complete?") from None
    except (TypeError, ValueError) as e:
        raise DataFormatError(f"{path}: unreadable timestep time: {e}") from None
    if not buf and not n:
        raise DataFormatError(f"{path}: SUMO FCD output with no vehicle, person or container element")
    if buf:
        yield _sumo_table(buf, path)


def _sumo_table(rows: list[dict[str, Any]], path: str) -> pd.DataFrame:
    import pandas as pd

    df = pd.DataFrame(rows)
    front = ["time", "kind", "id", "x", "y"]
    missing = [c for c in ("id", "x", "y") if c not in df.columns]
    if missing:
        raise DataFormatError(f"{path}: FCD elements lack attribute(s) {missing}")
    df = df[front + [c for c in df.columns if c not in front]]
    for c in df.columns:
        if c not in ("kind", "id", "type", "lane", "edge", "signals"):
            conv = pd.to_numeric(df[c], errors="coerce")
            if conv.notna().sum() == df[c].notna().sum():
                df[c] = conv
    return df


def _read_sumo_csv(df: pd.DataFrame, where: str) -> pd.DataFrame:
    """The CSV of ``xml2csv fcd.xml``: ``timestep_time;vehicle_id;vehicle_x;...`` (persons alike)."""
    import pandas as pd

    if "timestep_time" not in df.columns:
        raise DataFormatError(
            f"{where}: not SUMO FCD CSV (no 'timestep_time' column; found {list(df.columns)}); "
            "expected the output of SUMO's xml2csv on an FCD file"
        )
    parts = []
    for kind in ("vehicle", "person", "container"):
        prefix = kind + "_"
        own = [c for c in df.columns if str(c).startswith(prefix)]
        if f"{prefix}id" not in own:
            continue
        sub = df.loc[df[f"{prefix}id"].notna(), ["timestep_time"] + own]
        sub = sub.rename(columns={"timestep_time": "time", **{c: c[len(prefix) :] for c in own}})
        sub.insert(1, "kind", kind)
        parts.append(sub)
    if not parts or sum(map(len, parts)) == 0:
        raise DataFormatError(f"{where}: SUMO FCD CSV without any vehicle_id/person_id rows")
    out = pd.concat(parts, ignore_index=True, sort=False)
    front = ["time", "kind", "id", "x", "y"]
    missing = [c for c in front if c not in out.columns]
    if missing:
        raise DataFormatError(f"{where}: SUMO FCD CSV lacks column(s) {missing}")
    out["id"] = out["id"].astype(str)
    return out[front + [c for c in out.columns if c not in front]]


# ---------------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------------


def _existing(path: str | os.PathLike) -> str:
    path = as_path(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"no such file: {path}")
    if os.path.isdir(path):
        raise DataFormatError(f"{path} is a directory; pass a trajectory file")
    return path


def _damaged_file_errors() -> tuple[type[BaseException], ...]:
    """What reading a damaged text or gzip file raises from pandas, csv, gzip and zlib: all of
    them mean "unreadable file" (a truncated .gz ends in EOFError, a corrupt one in zlib.error)."""
    import csv
    import zlib

    import pandas as pd

    return (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, EOFError, zlib.error,
            csv.Error, gzip.BadGzipFile)  # fmt: skip


def _first_line(path: str) -> str:
    opener = gzip.open if path.lower().endswith(".gz") else open
    try:
        with opener(path, "rt", encoding="utf-8-sig", errors="replace") as fh:
            for line in fh:
                if line.strip():
                    return line
    except (OSError, EOFError, *_damaged_file_errors()) as e:  # type: ignore[misc]
        raise DataFormatError(f"{path} could not be read ({type(e).__name__}: {e}); is it complete?") from None
    raise DataFormatError(f"{path} is empty")


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _read_table(path: str, names: list[str] | None) -> pd.DataFrame:
    """A delimited text or Parquet file; the separator and the header are sniffed."""
    import pandas as pd

    low = path.lower()
    if low.endswith((".parquet", ".pq")):
        try:
            return pd.read_parquet(path)
        except ImportError as e:
            raise ImportError(f"reading Parquet needs pyarrow (pip install pyarrow): {e}") from None
        except Exception as e:  # pyarrow raises its own types for a file that is not Parquet
            raise DataFormatError(f"{path} is not a readable Parquet file: {e}") from None
    first = _first_line(path)
    if "\x00" in first:
        raise DataFormatError(f"{path} is a binary file, not a text table (Parquet files must end in .parquet)")
    sep = next((s for s in ("\t", ";", ",") if s in first), r"\s+")
    tokens = [tok.strip().strip('"') for tok in re.split(sep if sep != r"\s+" else r"\s+", first.strip())]
    header = None if names is not None or all(_is_number(tok) for tok in tokens if tok) else 0
    try:
        return pd.read_csv(path, sep=sep, header=header, encoding="utf-8-sig", low_memory=False)
    except _damaged_file_errors() as e:
        raise DataFormatError(f"{path} is not a readable table ({type(e).__name__}: {e})") from None


def _check_unique_columns(df: pd.DataFrame, cols: dict[str, Any], where: str) -> None:
    """A column the table names twice is ambiguous (pandas returns both): say which."""
    chosen = [c for v in cols.values() if v is not None for c in (v if isinstance(v, list) else [v])]
    twice = sorted({str(c) for c in chosen if int((df.columns == c).sum()) > 1})
    if twice:
        raise DataFormatError(
            f"{where}: the table has more than one column named {twice}; rename or drop the duplicates"
        )


def _numeric(col: pd.Series, name: object, where: str) -> pd.Series:
    """Numbers, accepting thousands separators ("1,156"); unparsable text raises."""
    import pandas as pd

    if pd.api.types.is_numeric_dtype(col) and not pd.api.types.is_bool_dtype(col):
        return col
    text = col.astype(str).str.strip().str.replace(r"(?<=\d),(?=\d{3}\b)", "", regex=True)
    conv = pd.to_numeric(text, errors="coerce")
    bad = conv.isna() & col.notna()
    if bad.any():
        i = int(np.flatnonzero(bad.to_numpy())[0])
        raise DataFormatError(
            f"{where}: column {name!r} should be numeric but has {int(bad.sum())} value(s) that are not "
            f"numbers, first {col.iloc[i]!r} at row {i}; is this the right column?"
        )
    return conv


def _check_finite_columns(df: pd.DataFrame, names: Sequence[str], where: str) -> None:
    for name in names:
        arr = column_floats(df[name], name, where)
        bad = ~np.isfinite(arr)
        if bad.any():
            raise InvalidInputError(
                f"{where}: {int(bad.sum())} missing value(s) in {name!r}, first at row {int(np.flatnonzero(bad)[0])}; "
                "drop or fill those rows first"
            )


def _check_positive(name: str, value: object) -> None:
    try:
        ok = float(value) > 0 and math.isfinite(float(value))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise InvalidInputError(f"{name} must be a positive number, got {value!r}")


__all__ = ["read_ngsim", "read_tracks", "NGSIM_FRAME_SECONDS"]
