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
"""

from __future__ import annotations

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


__all__ = ["describe_tracks", "OBJECT_TYPES"]
