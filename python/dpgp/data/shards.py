"""Sharded frames (issue 33): frames stored as a directory of Parquet shards, each a contiguous
range of the frames, and a small JSON manifest, so that a worker reads its own shard alone and no
process needs all frames.

::

    frames.to_parquet("frames/", shards=8)             # atomic; dpgp.make_frames(..., out=, shards=) too
    frames = dpgp.read_frames("frames/")               # all of them, as written
    m = dpgp.data.shards.read_manifest("frames/")      # what the directory holds: shards, ranges, units
    part, start = dpgp.data.shards.read_shard("frames/", 3)   # one shard, and its first frame's position

``part`` equals ``frames[start : start + len(part)]``; the shards in order make up the frames.

The directory holds ``manifest.json`` and ``shard-00000.parquet``, ``shard-00001.parquet``, ...:
one row per vehicle (``frame_number`` — the frame's position among all frames —, ``frame``
— its id; for ``(scene, time)`` ids the time, with ``scene`` beside it —, ``x, y, vx, vy``, and
``track`` and ``label`` when the frames have them). The manifest lists each shard's frame range
and vehicles, how ids and labels are stored, the units, the framing summary and the time order
(the full description is in the source, ``dpgp/data/_shardfile.py``). The guide's "Sharded
frames" section (Data and frames) shows the whole round.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import NamedTuple

from ._shardfile import MANIFEST, VERSION, ShardInfo, ShardManifest, read_parts
from ._shardfile import read_manifest as _read_manifest
from ._streamframing import frame_to_shards
from .frames import Frames, from_stored


class Shard(NamedTuple):
    """One shard's frames and ``start``, the position of its first frame among all frames."""

    frames: Frames
    start: int


def read_manifest(directory: str | os.PathLike) -> ShardManifest:
    """What a directory of sharded frames holds (:class:`ShardManifest`), from its manifest
    alone: the number of frames and points, each shard's file, frame range and points, how ids
    and labels are stored, the units, the framing summary and the time order.
    :class:`~dpgp.DataFormatError` naming the manifest if it is missing or damaged."""
    return _read_manifest(directory)


def read_shard(directory: str | os.PathLike | ShardManifest, i: int) -> Shard:
    """Shard ``i`` of a directory of sharded frames, read alone: its :class:`~dpgp.Frames` (with
    their ids, labels, track ids and the framing summary) and the global position of its first
    frame. ``directory`` may be a manifest already read, to save reading it again.
    :class:`~dpgp.InvalidInputError` for a shard number out of range,
    :class:`~dpgp.DataFormatError` naming the file for a shard missing or damaged."""
    manifest = directory if isinstance(directory, ShardManifest) else _read_manifest(directory)
    frames = from_stored(read_parts(manifest, i))
    return Shard(frames, manifest.shards[int(i)].start)


def iter_shards(directory: str | os.PathLike | ShardManifest) -> Iterator[Shard]:
    """Every shard in order, one at a time (only one shard's frames in memory at once)."""
    manifest = directory if isinstance(directory, ShardManifest) else _read_manifest(directory)
    for i in range(manifest.n_shards):
        yield read_shard(manifest, i)


def write_shards(
    frames: Frames, directory: str | os.PathLike, shards: int = 1, *, overwrite: bool = False
) -> ShardManifest:
    """``frames.to_parquet(directory, shards, overwrite=overwrite)``."""
    return frames.to_parquet(directory, shards, overwrite=overwrite)


__all__ = [
    "MANIFEST",
    "VERSION",
    "Shard",
    "ShardInfo",
    "frame_to_shards",
    "ShardManifest",
    "iter_shards",
    "read_manifest",
    "read_shard",
    "write_shards",
]
