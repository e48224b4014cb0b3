"""From a tracks table to frames: resample every track to a regular time grid, derive velocity
vectors, crop to a region of interest, and group the vehicles present at each grid time.

Everything is vectorised over the whole table (no Python loop over tracks or frames), so that
tens of millions of rows frame in seconds. A track is cut into *segments* wherever its samples
are more than ``max_gap`` apart; nothing is interpolated, differenced or smoothed across a
segment boundary.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any, Literal, overload

import numpy as np

from .._constants import DEFAULT_DT, FT_TO_M
from .._validate import check_roi
from ..exceptions import DataFormatError, InvalidInputError
from ._previous import HEADING_MIN_SPEED, LastRow, check_min_speed, in_frame_units, previous_steps
from ._shardfile import check_shards, check_target
from .frames import Frames
from .provenance import FramingSummary, describe_tracks

if TYPE_CHECKING:
    import pandas as pd

_UNITS = {"ft->m": FT_TO_M, "feet->metres": FT_TO_M, "feet->meters": FT_TO_M, "m->ft": 1 / FT_TO_M}
_GRID_EPS = 1e-6  # a sample within 1e-6 dt of a grid time counts as on it (float rounding)
_CHUNK = 1 << 18  # rows per batch in the smoothing solve (bounds its memory)
_BATCH = 1 << 20  # rows (plus grid points) per batch of the resampling
_MAX_GRID_NUMBER = 2.0**52  # grid numbers t / dt beyond this are not exact in float64
_MAX_RESAMPLED = 200_000_000  # vehicle-times on the grid (about 10 GB of temporaries beyond this)


def make_frames(
    tracks: Any,
    roi: tuple[float, float, float, float] | None = None,
    dt: float = DEFAULT_DT,
    velocity: str = "auto",
    smoothing: tuple[int, int] | None = None,
    units: str | float | None = None,
    *,
    max_gap: float | None = None,
    out: str | os.PathLike | None = None,
    shards: int = 1,
    overwrite: bool = False,
    heading_min_speed: float = HEADING_MIN_SPEED,
) -> Frames:
    """Frames from a tracks table: one frame per grid time with every vehicle in the ROI.

    Parameters
    ----------
    tracks
        A tracks table (pandas or polars) with columns ``track, t, x, y`` and optionally
        ``vx, vy`` and ``scene`` — what :func:`dpgp.read_tracks` and :func:`dpgp.read_ngsim`
        return. Inside a track, rows must be in increasing time order.
    roi
        ``(x_min, x_max, y_min, y_max)`` in the *table's* units (before ``units`` conversion),
        edges included; ``None`` keeps everything.
    dt
        Grid step in seconds. Grid times are the multiples of ``dt``; a track is sampled at
        those inside its time span, by linear interpolation between its two neighbouring
        samples — never outside the span, never across a gap longer than ``max_gap``.
    velocity
        ``"auto"``: the table's ``vx, vy`` if it has them, else ``"diff"``. ``"columns"``:
        require ``vx, vy``. ``"diff"``: differentiate positions at the table's own sampling
        rate (three-point central differences, second-order one-sided at a segment's ends,
        exact for quadratic motion; a two-sample segment gets the chord's slope), then
        interpolate to the grid. Velocities are vectors ``(vx, vy)``, not speeds.
    smoothing
        ``(window, order)``: Savitzky–Golay smoothing at the table's sampling rate — a
        least-squares polynomial of ``order`` over ``window`` (odd) consecutive samples, in
        time, so uneven sampling is handled; positions take its value, derived velocities its
        slope. Segments shorter than ``window`` are left unsmoothed (counted in the summary).
    units
        ``None`` (keep), ``"ft->m"`` (NGSIM feet to metres) or ``"m->ft"``, or a number to
        multiply positions and velocities by.
    max_gap
        Longest time between two samples of a track that is still interpolated, in seconds.
        Default: twice the larger of ``dt`` and the table's typical (median) sampling step,
        so that a missing sample or two is bridged but not a vehicle's absence.
    out, shards, overwrite
        A directory to also write the frames into, as ``shards`` Parquet shards in time order
        with a manifest (:meth:`Frames.to_parquet`, :mod:`dpgp.data.shards`; atomic, and an
        existing non-empty directory only with ``overwrite=True``). The target is checked
        before any framing; the framing's temporaries are freed before the shards are written.
    heading_min_speed
        m/s (converted when the frames' length unit is feet): a previous velocity slower than
        this gives no heading of its own, and the vehicle keeps the heading it last moved in
        (``frames.prev_heading``, :meth:`Frames.headings`).

    Returns
    -------
    Frames
        Frame ids are the grid times in seconds (``(scene, time)`` tuples when the table has a
        ``scene`` column). ``frames.tracks`` holds each row's track id (the table's own
        integer ids, else codes in the sorted order of its ids). ``frames.summary`` is a :class:`FramingSummary` that counts every
        vehicle-time left out and empty frame dropped. ``frames.prev_v`` holds each vehicle's
        velocity one grid step earlier (NaN where its track was not resampled there; inside the
        ROI or not) and ``frames.prev_heading`` the heading it was last travelling in
        (:meth:`Frames.headings` says how it is carried through stops).
    """
    min_speed = check_min_speed(heading_min_speed)
    if out is None:
        if shards != 1 or overwrite:
            raise InvalidInputError("shards and overwrite say how to write the frames: give out=directory too")
        return _frames(tracks, roi, dt, velocity, smoothing, units, max_gap, min_speed)
    check_shards(shards)
    check_target(out, overwrite)
    frames = _frames(tracks, roi, dt, velocity, smoothing, units, max_gap, min_speed)
    frames.to_parquet(out, shards, overwrite=overwrite)
    return frames


def _frames(
    tracks: Any, roi: Any, dt: Any, velocity: str, smoothing: Any, units: Any, max_gap: Any, min_speed: float
) -> Frames:
    """make_frames' frames (its temporaries go when this returns)."""
    res = _resample(tracks, roi, dt, velocity, smoothing, units, max_gap, heading_min_speed=min_speed)
    k, scene = res["k"], res["scene"]
    # Frames in order of (scene, grid time); inside a frame, vehicles in track order.
    keys = (res["track"], k) if scene is None else (res["track"], k, scene)
    order = np.lexsort(keys)
    ks = k[order]
    new = np.empty(len(ks), dtype=bool)
    new[:1] = True
    np.not_equal(ks[1:], ks[:-1], out=new[1:])
    if scene is not None:
        ss = scene[order]
        new[1:] |= ss[1:] != ss[:-1]
    starts = np.flatnonzero(new)
    times = np.round(ks[starts] * res["dt"], 9)
    if scene is None:
        ids: np.ndarray = times
    else:
        labels = res["scene_labels"][ss[starts]]
        ids = np.empty(len(starts), dtype=object)
        ids[:] = list(zip(labels.tolist(), times.tolist()))
    n_slots = res["n_slots"]
    xy = np.column_stack([res["x"][order], res["y"][order]])
    v = np.column_stack([res["vx"][order], res["vy"][order]])
    # keep each vehicle's track (its code among the table's track ids) to follow it over time
    # gathered column by column, each source freed once read (peak memory)
    prev_v = np.empty((len(ks), 2))
    prev_v[:, 0] = res.pop("pvx")[order]
    prev_v[:, 1] = res.pop("pvy")[order]
    frames = Frames(
        ids,
        np.r_[starts, len(ks)],
        xy,
        v,
        tracks=res["track"][order],
        prev_v=prev_v,
        prev_heading=res.pop("ph")[order],
        heading_min_speed=min_speed,
    )
    summary = FramingSummary(
        **res["counts"],
        n_points=len(ks),
        n_frames=len(starts),
        n_empty_frames=n_slots - len(starts),
    )
    frames.summary = summary
    return frames


def resample_tracks(
    tracks: Any,
    dt: float = DEFAULT_DT,
    velocity: str = "auto",
    smoothing: tuple[int, int] | None = None,
    units: str | float | None = None,
    *,
    max_gap: float | None = None,
    roi: tuple[float, float, float, float] | None = None,
) -> pd.DataFrame:
    """The resampled tracks behind :func:`make_frames`, as a table.

    Same arguments as :func:`make_frames`. Returns one row per vehicle-time on the grid:
    ``track, t, x, y, vx, vy`` (and ``scene``), sorted by track then time, with the
    :class:`FramingSummary` (without the frame counts) in ``table.attrs["dpgp_summary"]``.
    """
    import pandas as pd

    res = _resample(tracks, roi, dt, velocity, smoothing, units, max_gap)
    tr = res["track"]
    # rows come out in the table's order of tracks; sort them by track if that was not
    order = slice(None) if np.all(tr[1:] >= tr[:-1]) else np.lexsort((res["k"], tr))
    out = pd.DataFrame(
        {
            "track": res["track_labels"][tr[order]],
            "t": np.round(res["k"][order] * res["dt"], 9),
            "x": res["x"][order],
            "y": res["y"][order],
            "vx": res["vx"][order],
            "vy": res["vy"][order],
        }
    )
    if res["scene"] is not None:
        out["scene"] = res["scene_labels"][res["scene"][order]]
    out.attrs["dpgp_summary"] = dict(res["counts"])
    return out


# ---------------------------------------------------------------------------------------------
# the engine
# ---------------------------------------------------------------------------------------------


def _check_options(roi: Any, dt: Any, velocity: Any, smoothing: Any, units: Any, max_gap: Any) -> tuple[Any, ...]:
    """The framing options checked: ``(roi, dt, smoothing, unit scale, unit name, max_gap)``
    (shared by :func:`_resample` and the windowed framing of :mod:`._streamframing`)."""
    dt = _positive("dt", dt, "seconds between frames")
    if max_gap is not None:
        max_gap = _positive("max_gap", max_gap, "seconds")
    roi = None if roi is None else check_roi(roi)
    scale, units_name = _check_units(units)
    if velocity not in ("auto", "columns", "diff"):
        raise InvalidInputError(f"velocity must be 'auto', 'columns' or 'diff', got {velocity!r}")
    return roi, dt, _check_smoothing(smoothing), scale, units_name, max_gap


@overload
def _resample(
    tracks: Any,
    roi: Any,
    dt: Any,
    velocity: str,
    smoothing: Any,
    units: Any,
    max_gap: Any,
    *,
    heading_min_speed: float = ...,
) -> dict[str, Any]: ...


@overload
def _resample(
    tracks: Any,
    roi: Any,
    dt: Any,
    velocity: str,
    smoothing: Any,
    units: Any,
    max_gap: Any,
    *,
    partial: Literal[True],
    heading_min_speed: float = ...,
    length_unit: str | None = ...,
    carry: Any = ...,
    keep: Any = ...,
) -> dict[str, Any] | None: ...


def _resample(
    tracks: Any,
    roi: Any,
    dt: Any,
    velocity: str,
    smoothing: Any,
    units: Any,
    max_gap: Any,
    *,
    partial: bool = False,
    heading_min_speed: float = HEADING_MIN_SPEED,
    length_unit: str | None = "table",
    carry: Any = None,
    keep: Any = None,
) -> dict[str, Any] | None:
    """The resampled vehicle-times of a tracks table, with the counts of the framing summary,
    and each one's previous step (``pvx, pvy, ph``: :mod:`._previous`).

    ``partial``: the table is one time window of a larger one (:mod:`._streamframing`), which
    may hold no grid time or no vehicle in the ROI: None then, rather than an error. Such a
    window gives the frames' ``length_unit`` (its table has lost the reader's), a ``carry`` of
    every track's last grid point in earlier windows (:class:`._previous.PerTrack`, by the
    tracks' own integer ids), and ``keep``, which grid numbers are its own."""
    roi, dt, smoothing, scale, units_name, max_gap = _check_options(roi, dt, velocity, smoothing, units, max_gap)

    cols = _columns(tracks)
    has_v = "vx" in cols and "vy" in cols
    if velocity == "columns" and not has_v:
        raise DataFormatError("velocity='columns' needs vx and vy columns in the table; use velocity='diff'")
    mode = "columns" if (velocity == "auto" and has_v) or velocity == "columns" else "diff"

    tr, track_labels = _track_codes(cols["track"])
    t = _floats(cols, "t")
    x, y = _floats(cols, "x"), _floats(cols, "y")
    vx = vy = None
    if mode == "columns":
        hint = "use velocity='diff' to derive velocities from positions"
        vx, vy = _floats(cols, "vx", hint=hint), _floats(cols, "vy", hint=hint)
    sc, scene_labels = (None, None) if "scene" not in cols else _track_codes(cols["scene"])
    n = len(t)
    if n == 0:
        raise DataFormatError("the tracks table has no rows")

    # Rows of a track must be contiguous; if the table is interleaved (e.g. sorted by time),
    # group them, keeping each track's own row order. Only track, time (and scene) are
    # reordered here; positions and velocities are gathered batch by batch (memory).
    chg = tr[1:] != tr[:-1]
    block_ids = tr[np.flatnonzero(np.r_[True, chg])]
    del chg
    n_tracks = len(np.unique(block_ids))
    perm = None
    if n_tracks != len(block_ids):
        perm = np.argsort(tr, kind="stable")
        tr, t = tr[perm], t[perm]
        if sc is not None:
            sc = sc[perm]
    del block_ids
    if max_gap is None:
        max_gap = 2.0 * max(dt, _typical_step(tr, t))

    starts, n_gaps = _segment_starts(tr, t, sc, max_gap, track_labels)
    ends = np.r_[starts[1:], n]
    seg_len = ends - starts
    seg_track = tr[starts]

    t_abs = float(max(abs(t[0]), abs(t[-1]), np.abs(t).max()))
    if t_abs / dt > _MAX_GRID_NUMBER:
        raise InvalidInputError(
            f"dt={dt:g} s is too small for times up to {t_abs:g} s: grid numbers would exceed 2^52 and lose "
            "precision; use a larger dt, or subtract the start time from t"
        )
    # Snap to a grid time within 1e-6 dt (float rounding), but never more than 1e-6 s: with a
    # huge dt, a sample seconds away from a grid time must not count as on it.
    eps = _GRID_EPS * min(1.0, 1.0 / dt)
    s0, s1 = t[starts], t[ends - 1]
    k0 = np.ceil(s0 / dt - eps).astype(np.int64)
    k1 = np.floor(s1 / dt + eps).astype(np.int64)
    cont = seg_track[1:] == seg_track[:-1]
    n_gap_times = int(np.maximum(k0[1:] - k1[:-1] - 1, 0)[cont].sum())
    cnt = np.maximum(k1 - k0 + 1, 0)
    between = cnt == 0
    single = (seg_len == 1) & ~between if mode == "diff" else np.zeros(len(starts), dtype=bool)
    cnt[single] = 0
    G = int(cnt.sum())
    seg_scene = None if sc is None else sc[starts]
    counts = dict(
        dt=dt,
        max_gap=max_gap,
        units=units_name,
        velocity=mode,
        smoothing=smoothing,
        roi=None if roi is None else tuple(float(r * scale) for r in roi),
        n_rows=n,
        n_tracks=n_tracks,
        n_segments=len(starts),
        n_gaps=n_gaps,
        n_gap_times=n_gap_times,
        n_segments_between_grid_times=int(between.sum()),
        n_rows_between_grid_times=int(seg_len[between].sum()),
        n_single_sample_segments=int(single.sum()),
        n_unsmoothed_segments=0 if smoothing is None else int(((seg_len < smoothing[0]) & (cnt > 0)).sum()),
        n_resampled=G,
        n_scenes=1 if sc is None else len(np.unique(seg_scene)),  # type: ignore[arg-type]
        **describe_tracks(tracks, units_name, scale),
    )
    if G > _MAX_RESAMPLED:
        raise InvalidInputError(
            f"dt={dt:g} s gives {G:,} vehicle-times on the grid, more than {_MAX_RESAMPLED:,}; use a larger dt "
            "(or a smaller max_gap, which stops tracks being bridged across long gaps)"
        )
    if G == 0:
        if partial:
            return None
        raise InvalidInputError(
            f"no track reaches a grid time: dt={dt:g} s is longer than every track's time span "
            f"(and max_gap={max_gap:g} s cuts tracks at longer gaps); use a smaller dt or a larger max_gap"
        )

    # The heading floor in the table's units (velocities are scaled to the frames' units last).
    unit = counts["length_unit"] if length_unit == "table" else length_unit
    floor = in_frame_units(heading_min_speed, unit) / scale
    if carry is None:
        carry, seg_id = LastRow(), seg_track
    else:
        seg_id = np.asarray(track_labels[seg_track], dtype=np.int64)
    # Resample in batches of whole segments, so that temporaries stay small however long the
    # table: each batch holds about _BATCH grid points plus rows.
    cost = np.cumsum(cnt + seg_len)
    cuts = np.searchsorted(cost, np.arange(_BATCH, int(cost[-1]), _BATCH), side="left")
    bounds = np.unique(np.r_[0, cuts + 1, len(starts)])
    bounds = bounds[bounds <= len(starts)]
    parts = []
    for sa, sb in zip(bounds[:-1], bounds[1:]):
        r0, r1 = int(starts[sa]), int(ends[sb - 1])
        rows = slice(r0, r1) if perm is None else perm[r0:r1]
        with np.errstate(over="ignore"):  # overflow (absurd units or steps) is checked and reported below
            part = _resample_batch(
                t[r0:r1],
                x[rows],
                y[rows],
                None if vx is None else vx[rows],
                None if vy is None else vy[rows],
                starts[sa:sb] - r0,
                ends[sa:sb] - r0,
                k0[sa:sb],
                cnt[sa:sb],
                dt,
                mode,
                smoothing,
                roi,
                (seg_id[sa:sb], floor, carry, keep),
            )
        part["seg"] += sa
        parts.append(part)
    out = {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}
    seg_g = out.pop("seg")
    if len(seg_g) == 0:
        if partial:
            return None
        raise InvalidInputError(
            "no vehicle enters the ROI x [{:g}, {:g}], y [{:g}, {:g}]".format(*roi)
            + f": the data span x [{x.min():g}, {x.max():g}], y [{y.min():g}, {y.max():g}]"
            " (the ROI is in the table's units, before any units conversion)"
        )
    for key in ("x", "y", "vx", "vy"):
        if not np.isfinite(out[key]).all():  # differences or interpolation beyond the float range
            raise InvalidInputError(
                f"{key} overflows the floating-point range when resampled (positions up to "
                f"{max(np.abs(x).max(), np.abs(y).max()):g}, samples as close as {_min_step(t):g} s apart); "
                "check the units of t, x and y"
            )
    counts["n_outside_roi"] = G - len(seg_g)
    if scale != 1.0:
        for key in ("x", "y", "vx", "vy", "pvx", "pvy"):
            largest = float(np.max(np.abs(out[key]), initial=0.0, where=~np.isnan(out[key])))
            with np.errstate(over="ignore"):  # checked just below, with a message that says what to do
                out[key] *= scale
            if np.isinf(out[key]).any() or (key in ("x", "y", "vx", "vy") and np.isnan(out[key]).any()):
                raise InvalidInputError(
                    f"units={units!r} takes {key} beyond the floating-point range (largest |{key}| "
                    f"{largest:g}); use a smaller factor"
                )
    # Grid times from the first to the last one any segment reaches, per scene.
    has = cnt > 0
    if seg_scene is None:
        n_slots = int(k1[has].max() - k0[has].min() + 1)
    else:
        sid, lo_k, hi_k = seg_scene[has], k0[has], k1[has]
        order = np.argsort(sid, kind="stable")
        sid, lo_k, hi_k = sid[order], lo_k[order], hi_k[order]
        b = np.flatnonzero(np.r_[True, sid[1:] != sid[:-1]])
        n_slots = int((np.maximum.reduceat(hi_k, b) - np.minimum.reduceat(lo_k, b) + 1).sum())
    return dict(
        dt=dt,
        track=seg_track[seg_g],
        track_labels=track_labels,
        scene=None if seg_scene is None else seg_scene[seg_g],
        scene_labels=scene_labels,
        n_slots=n_slots,
        counts=counts,
        **out,
    )


def _min_step(t: np.ndarray) -> float:
    steps = np.diff(t)
    steps = steps[steps > 0]
    return float(steps.min()) if len(steps) else 0.0


def _typical_step(tr: np.ndarray, t: np.ndarray) -> float:
    """The median time between consecutive samples of a track, from up to a million of them."""
    n = len(t)
    i = np.arange(0, n - 1, max(1, (n - 1) // 1_000_000))
    i = i[tr[i] == tr[i + 1]]
    return float(np.median(t[i + 1] - t[i])) if len(i) else 0.0


def _segment_starts(
    tr: np.ndarray, t: np.ndarray, sc: np.ndarray | None, max_gap: float, labels: np.ndarray
) -> tuple[np.ndarray, int]:
    """First row of every segment: a new one at each track change or gap > max_gap.

    Raises if time does not increase inside a track, or a track changes scene. Works through the
    rows in batches to keep its temporaries small.
    """
    n = len(t)
    found = [np.zeros(1, dtype=np.int64)]
    n_gaps = 0
    limit = max_gap * (1 + 1e-9)
    for a in range(1, n, _BATCH):
        b = min(a + _BATCH, n)
        same = tr[a:b] == tr[a - 1 : b - 1]
        step = t[a:b] - t[a - 1 : b - 1]
        back = same & (step <= 0)
        if back.any():
            i = a - 1 + int(np.flatnonzero(back)[0])
            what = "repeats" if t[i + 1] == t[i] else "goes backwards"
            raise InvalidInputError(
                f"time {what} inside track {_label(labels[tr[i]])}: t={t[i + 1]:g} s follows t={t[i]:g} s; "
                "sort the table by track and time (tracks.sort_values(['track', 't'])) if the rows are "
                "only out of order, else fix the track ids"
            )
        if sc is not None:
            cross = same & (sc[a:b] != sc[a - 1 : b - 1])
            if cross.any():
                i = a - 1 + int(np.flatnonzero(cross)[0])
                raise InvalidInputError(
                    f"track {_label(labels[tr[i]])} spans two scenes; give each scene its own track ids"
                )
        gap = same & (step > limit)
        n_gaps += int(gap.sum())
        found.append(np.flatnonzero(~same | gap) + a)
    return np.concatenate(found), n_gaps


def _resample_batch(
    t: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    vx: np.ndarray | None,
    vy: np.ndarray | None,
    starts: np.ndarray,
    ends: np.ndarray,
    k0: np.ndarray,
    cnt: np.ndarray,
    dt: float,
    mode: str,
    smoothing: tuple[int, int] | None,
    roi: tuple[float, float, float, float] | None,
    previous: tuple[np.ndarray, float, Any, Any] | None = None,
) -> dict[str, np.ndarray]:
    """Resample consecutive segments at their grid times; the arrays hold just their rows,
    ``starts/ends`` index into them. ``previous``: ``(track of each segment, speed floor, carry,
    keep)`` adds each point's previous step (:mod:`._previous`) as ``pvx, pvy, ph``, after
    keeping only the grid numbers ``keep(k)`` accepts (None: all)."""
    G = int(cnt.sum())
    seg = np.repeat(np.arange(len(starts)), cnt)
    k = np.arange(G, dtype=np.int64)
    k -= np.repeat(np.cumsum(cnt) - cnt - k0, cnt)
    tg = k * dt
    # The sample at or before each grid time, by one search: lay the segments end to end on one
    # increasing axis (each shifted to begin at its own base), so that searchsorted sees them all.
    s0, s1 = t[starts], t[ends - 1]
    shift = np.cumsum(np.r_[0.0, (s1 - s0)[:-1] + 1.0 + dt]) - s0
    key = np.repeat(shift, ends - starts)
    key += t
    j = np.searchsorted(key, shift[seg] + tg, side="right") - 1
    del key
    lo, hi = starts[seg], ends[seg]
    # The shifted times round at the scale of the shift, which depends on the other segments of
    # the batch: correct j to the last sample at or before tg in its own times, so that a grid
    # point does not depend on how the table was cut into batches (or into time windows).
    np.clip(j, lo, hi - 1, out=j)
    while True:
        down = (j > lo) & (t[j] > tg)
        up = j + 1 < hi
        up[up] = t[j[up] + 1] <= tg[up]
        if not (down.any() or up.any()):
            break
        j[down] -= 1
        j[up] += 1
    np.clip(j, lo, np.maximum(hi - 2, lo), out=j)
    j1 = np.minimum(j + 1, hi - 1)
    den = t[j1] - t[j]
    w = np.divide(tg - t[j], den, out=np.zeros(G), where=den > 0)
    np.clip(w, 0.0, 1.0, out=w)  # never extrapolate beyond a segment's first or last sample
    del den, tg

    short = None if smoothing is None else (hi - lo) < smoothing[0]
    if short is None or short.all():
        gx, gy = _lerp(x[j], x[j1], w), _lerp(y[j], y[j1], w)
        if mode == "diff":
            gvx, gvy = (
                _lerp(a, b, w)
                for a, b in zip(_diff_velocity(t, (x, y), j, lo, hi), _diff_velocity(t, (x, y), j1, lo, hi))
            )
    else:
        px0, py0, dvx0, dvy0 = _smoothed(t, x, y, j, lo, hi, smoothing, short)  # type: ignore[arg-type]
        px1, py1, dvx1, dvy1 = _smoothed(t, x, y, j1, lo, hi, smoothing, short)  # type: ignore[arg-type]
        gx, gy = _lerp(px0, px1, w), _lerp(py0, py1, w)
        gvx, gvy = _lerp(dvx0, dvx1, w), _lerp(dvy0, dvy1, w)
    if mode == "columns":
        gvx, gvy = _lerp(vx[j], vx[j1], w), _lerp(vy[j], vy[j1], w)  # type: ignore[index]
    out = {"seg": seg, "k": k, "x": gx, "y": gy, "vx": gvx, "vy": gvy}
    if previous is not None:
        # Before the ROI crop: a vehicle entering the ROI has a previous step just outside it.
        seg_id, floor, carry, keep = previous
        if keep is not None:  # a time window keeps only its own grid points (and carries them on)
            inside = keep(k)
            if not inside.all():
                out = {key: arr[inside] for key, arr in out.items()}
        out["pvx"], out["pvy"], out["ph"] = previous_steps(
            seg_id[out["seg"]], out["k"], out["vx"], out["vy"], floor, carry
        )
        gx, gy = out["x"], out["y"]
    if roi is not None:
        inside = (gx >= roi[0]) & (gx <= roi[1]) & (gy >= roi[2]) & (gy <= roi[3])
        if not inside.all():
            out = {key: arr[inside] for key, arr in out.items()}
    return out


def _label(v: Any) -> str:
    return repr(v.item() if isinstance(v, np.generic) else v)


def _lerp(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    out = b - a
    out *= w
    out += a
    return out


def _diff_velocity(
    t: np.ndarray, ps: tuple[np.ndarray, ...], i: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> list[np.ndarray]:
    """d/dt of each position array at rows ``i``, inside segments ``[lo, hi)``.

    The derivative at t_i of the quadratic through three neighbouring samples (a, a+1, a+2),
    chosen centred on i where possible: the central difference inside a segment, the
    second-order one-sided difference at its ends, for any (uneven) spacing. A two-sample
    segment gets the chord's slope.
    """
    a = np.clip(i - 1, lo, np.maximum(hi - 3, lo))
    three = hi - lo >= 3
    b = np.minimum(a + 1, hi - 1)
    c = np.where(three, a + 2, b)
    te, ta, tb, tc = t[i], t[a], t[b], t[c]
    with np.errstate(divide="ignore", invalid="ignore"):
        wa = ((te - tb) + (te - tc)) / ((ta - tb) * (ta - tc))
        wb = ((te - ta) + (te - tc)) / ((tb - ta) * (tb - tc))
        wc = ((te - ta) + (te - tb)) / ((tc - ta) * (tc - tb))
        chord = 1.0 / (tb - ta)
    out = []
    with np.errstate(invalid="ignore"):  # the branch np.where does not take may hold inf * 0
        for p in ps:
            pa, pb = p[a], p[b]
            out.append(np.where(three, wa * pa + wb * pb + wc * p[c], (pb - pa) * chord))
    return out


def _smoothed(
    t: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    i: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    smoothing: tuple[int, int],
    short: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Savitzky–Golay value and slope at rows ``i``: a least-squares polynomial fitted, in time,
    to ``window`` consecutive samples of the segment, centred on i where the segment allows.
    Rows of segments shorter than the window (``short``) get raw positions and differences."""
    window, order = smoothing
    px, py = x[i].copy(), y[i].copy()
    vx, vy = _diff_velocity(t, (x, y), i, lo, hi)
    long_rows = np.flatnonzero(~short)
    pw = np.arange(order + 1)
    hank = pw[:, None] + pw[None, :]
    for c0 in range(0, len(long_rows), _CHUNK):
        rows = long_rows[c0 : c0 + _CHUNK]
        ii, l, h = i[rows], lo[rows], hi[rows]
        start = np.clip(ii - window // 2, l, h - window)
        te = t[ii]
        # time in units of half the window's span keeps the powers near 1 (conditioning)
        scale = (t[start + window - 1] - t[start]) / 2.0
        S = np.zeros((len(rows), 2 * order + 1))
        B = np.zeros((2, len(rows), order + 1))
        x0, y0 = x[ii], y[ii]  # positions relative to the centre: large coordinates lose nothing
        for m in range(window):
            jj = start + m
            tau = (t[jj] - te) / scale
            dx, dy = x[jj] - x0, y[jj] - y0
            p = np.ones_like(tau)
            for q in range(2 * order + 1):
                S[:, q] += p
                if q <= order:
                    B[0, :, q] += p * dx
                    B[1, :, q] += p * dy
                p = p * tau
        coef = np.linalg.solve(S[:, hank][None], B[..., None])[..., 0]
        px[rows] = x0 + coef[0, :, 0]
        py[rows] = y0 + coef[1, :, 0]
        vx[rows] = coef[0, :, 1] / scale
        vy[rows] = coef[1, :, 1] / scale
    return px, py, vx, vy


# ---------------------------------------------------------------------------------------------
# argument checks
# ---------------------------------------------------------------------------------------------


def _columns(tracks: Any) -> dict[str, np.ndarray]:
    """The canonical columns of a pandas or polars tracks table, as numpy arrays (no copy)."""
    names = getattr(tracks, "columns", None)
    if names is None or not hasattr(tracks, "__getitem__"):
        raise DataFormatError(
            f"make_frames takes a tracks table (a DataFrame), got {type(tracks).__name__}; "
            "build one with dpgp.read_tracks or dpgp.read_ngsim"
        )
    names = list(names)
    missing = [c for c in ("track", "t", "x", "y") if c not in names]
    if missing:
        raise DataFormatError(
            f"the tracks table has no column(s) {missing} (it has {names}); make_frames needs "
            "track, t, x, y — load the data with dpgp.read_tracks(df, id=..., t=..., x=..., y=...) first"
        )
    return {c: tracks[c].to_numpy() for c in ("track", "t", "x", "y", "vx", "vy", "scene") if c in names}


def _floats(cols: dict[str, np.ndarray], name: str, hint: str = "drop or fill those rows first") -> np.ndarray:
    try:
        arr = np.asarray(cols[name], dtype=np.float64)
    except (TypeError, ValueError):
        raise DataFormatError(f"column {name!r} must be numeric") from None
    bad = ~np.isfinite(arr)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InvalidInputError(
            f"column {name!r} has {int(bad.sum())} NaN or infinite value(s), first at row {i}; {hint}"
        )
    return arr


def _track_codes(col: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Integer codes of an id column and the labels they stand for."""
    if col.dtype.kind in "iu":
        lo = int(col.min()) if len(col) else 0
        codes = col.astype(np.int64, copy=False)
        if lo >= 0 and int(col.max()) < 4 * len(col) + 1024:
            return codes, np.arange(int(col.max()) + 1 if len(col) else 0)  # ids are their own labels
    import pandas as pd

    try:
        if pd.isna(col).any():
            raise InvalidInputError("the track (or scene) column has missing values; every row needs an id")
        codes, labels = pd.factorize(col, sort=True)
    except TypeError as e:  # lists as ids, or numbers mixed with strings (no order)
        raise DataFormatError(f"track (and scene) ids must be numbers or strings of one kind ({e})") from None
    return codes.astype(np.int64, copy=False), np.asarray(labels)


def _positive(name: str, value: Any, what: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{name} must be a positive number ({what}), got {value!r}") from None
    if not (v > 0 and np.isfinite(v)):
        raise InvalidInputError(f"{name} must be a positive number ({what}), got {value!r}")
    return v


def _check_units(units: Any) -> tuple[float, str | None]:
    if units is None:
        return 1.0, None
    if isinstance(units, str):
        key = units.replace(" ", "").lower()
        if key in _UNITS:
            return _UNITS[key], key
        raise InvalidInputError(f"units must be None, 'ft->m', 'm->ft' or a positive factor, got {units!r}")
    return _positive("units", units, "a factor applied to positions and velocities"), f"x{float(units):g}"


def _check_smoothing(smoothing: Any) -> tuple[int, int] | None:
    if smoothing is None:
        return None
    try:
        window, order = (int(v) for v in smoothing)
    except (TypeError, ValueError):
        raise InvalidInputError(f"smoothing must be (window, order), got {smoothing!r}") from None
    if window < 3 or window % 2 == 0 or not 1 <= order < window:
        raise InvalidInputError(
            f"smoothing (window, order) needs an odd window >= 3 and 1 <= order < window, got {smoothing!r}"
        )
    return window, order


__all__ = ["FramingSummary", "make_frames", "resample_tracks", "FT_TO_M"]
