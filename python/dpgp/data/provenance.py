"""What frames keep of the tracks they were made from, beyond positions and velocities.

:func:`dpgp.make_frames` records three things in its :class:`~dpgp.FramingSummary` (and so in a
model file) that exports need and the numbers alone do not say:

``length_unit``  ``"m"`` or ``"ft"``: the unit of the frames' positions, from the table's own
                 unit (``read_ngsim``: feet; ``read_tracks`` presets: metres) and the
                 ``units=`` conversion; ``None`` when neither says.
``object_type``  ``"vehicle"`` or ``"pedestrian"``, from the reader's preset (ETH/UCY:
                 pedestrians; NGSIM, highD, inD, INTERACTION, SUMO: vehicles), else ``None``.
``object_size``  ``(length, width)`` in the frames' units: the medians over tracks of the
                 table's size columns (NGSIM ``v_length``/``v_Width``; ``length``/``width``),
                 else ``None``. Generated vehicles are not tracked ones, so one typical size
                 is what a model can honestly keep.

The summary class lives here, below :mod:`.frames` and :mod:`.framing`, so that a reader of
stored frames (:mod:`.shards`) can rebuild it; :mod:`.framing` re-exports it.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np

#: The reader's format (``table.attrs["dpgp"]["format"]``) -> the kind of object it tracks.
OBJECT_TYPES = {
    "eth_ucy": "pedestrian",
    "ngsim": "vehicle",
    "highd": "vehicle",
    "ind": "vehicle",
    "interaction": "vehicle",
    "sumo": "vehicle",
}
# Size columns, (length, width), in the order they are looked for.
_SIZE_COLUMNS = (("v_length", "v_Width"), ("length", "width"))
# What a units= conversion turns positions into, whatever they were.
_CONVERTED = {"ft->m": "m", "feet->metres": "m", "feet->meters": "m", "m->ft": "ft"}


@dataclass(frozen=True)
class FramingSummary:
    """What :func:`make_frames` did, and every vehicle-time it left out and why.

    Counts of *segments* refer to pieces of tracks between gaps longer than ``max_gap``.
    ``roi`` is in the output units (after ``units`` conversion). ``print(summary)`` gives a
    readable report.
    """

    dt: float
    max_gap: float
    roi: tuple[float, float, float, float] | None
    units: str | None
    velocity: str  # "columns" (the table's vx, vy) or "diff" (central differences)
    smoothing: tuple[int, int] | None
    n_rows: int  # input rows
    n_tracks: int
    n_segments: int
    n_gaps: int  # gaps longer than max_gap, where a track was cut
    n_gap_times: int  # grid times inside those gaps: not interpolated
    n_segments_between_grid_times: int  # segments whose time span holds no grid time
    n_rows_between_grid_times: int  # ... and their rows
    n_single_sample_segments: int  # one sample, no velocity to difference: left out (diff only)
    n_unsmoothed_segments: int  # shorter than the smoothing window: plain differences
    n_resampled: int  # vehicle-times on the grid
    n_outside_roi: int  # ... of which outside the ROI
    n_points: int  # vehicle observations in the frames
    n_frames: int
    n_empty_frames: int  # grid times with no vehicle in the ROI: dropped
    n_scenes: int
    # What exports need (dpgp.provenance): "m"/"ft", "vehicle"/"pedestrian", (length, width)
    length_unit: str | None = None
    object_type: str | None = None
    object_size: tuple[float, float] | None = None

    def to_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> FramingSummary:
        """The summary :meth:`to_dict` gave, after a trip through JSON (lists back to tuples);
        keys a newer writer added are ignored."""
        known = {f.name for f in fields(cls)}
        s = {k: v for k, v in d.items() if k in known}
        for key in ("roi", "smoothing", "object_size"):
            if s.get(key) is not None:
                s[key] = tuple(s[key])
        return cls(**s)

    def __str__(self) -> str:
        roi = "none" if self.roi is None else "x [{:g}, {:g}], y [{:g}, {:g}]".format(*self.roi)
        lines = [
            f"{self.n_frames} frames, {self.n_points} vehicle observations "
            f"(dt {self.dt:g} s, ROI {roi}, units {self.units or 'as in the table'}"
            f"{' (' + self.length_unit + ')' if self.length_unit else ''}, "
            f"velocity from {self.velocity}{', smoothed ' + str(self.smoothing) if self.smoothing else ''})",
            f"input: {self.n_rows} rows, {self.n_tracks} tracks"
            + (f", {self.n_scenes} scenes" if self.n_scenes > 1 else "")
            + f"; cut at {self.n_gaps} gaps longer than {self.max_gap:g} s into {self.n_segments} segments",
            f"resampled: {self.n_resampled} vehicle-times; {self.n_outside_roi} outside the ROI",
            "left out:",
            f"  {self.n_empty_frames} empty frames (grid times with no vehicle in the ROI)",
            f"  {self.n_gap_times} vehicle-times inside gaps (not interpolated)",
            f"  {self.n_segments_between_grid_times} segments ({self.n_rows_between_grid_times} rows) "
            "too short to reach a grid time",
            f"  {self.n_single_sample_segments} single-sample segments (no velocity to difference)",
        ]
        if self.n_unsmoothed_segments:
            lines.append(
                f"note: {self.n_unsmoothed_segments} segments shorter than the smoothing window were not smoothed"
            )
        return "\n".join(lines)


def describe_tracks(tracks: Any, units: str | None, scale: float) -> dict[str, Any]:
    """``length_unit``, ``object_type`` and ``object_size`` of frames made from ``tracks`` with
    the conversion ``units`` (make_frames' normalised key, or None) of factor ``scale``."""
    attrs = getattr(tracks, "attrs", None) or {}
    meta = attrs.get("dpgp") if isinstance(attrs, dict) else None
    meta = meta if isinstance(meta, dict) else {}
    source = meta.get("units") if meta.get("units") in ("m", "ft") else None
    if units is None:
        unit = source
    else:
        unit = _CONVERTED.get(units)  # a bare factor: the result's unit is unknown
    return {
        "length_unit": unit,
        "object_type": OBJECT_TYPES.get(str(meta.get("format", "")).lower()),
        "object_size": _median_size(tracks, scale),
    }


def _median_size(tracks: Any, scale: float) -> tuple[float, float] | None:
    names = list(getattr(tracks, "columns", []))
    for length, width in _SIZE_COLUMNS:
        if length in names and width in names and "track" in names:
            try:
                track = np.asarray(tracks["track"].to_numpy())
                ln = np.asarray(tracks[length].to_numpy(), dtype=np.float64)
                wd = np.asarray(tracks[width].to_numpy(), dtype=np.float64)
            except (TypeError, ValueError):
                return None  # not numeric: no size rather than a failed framing
            # one value per track (its first row), so long tracks do not outweigh short ones
            _, first = np.unique(track, return_index=True)
            ln, wd = ln[first], wd[first]
            ok = np.isfinite(ln) & np.isfinite(wd) & (ln > 0) & (wd > 0)
            if not ok.any():
                return None
            return (float(np.median(ln[ok]) * scale), float(np.median(wd[ok]) * scale))
    return None


__all__ = ["FramingSummary", "describe_tracks", "OBJECT_TYPES"]
