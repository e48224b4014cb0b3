"""Stage 1, data: recorded tracks in, frames out (:mod:`.tracks` reads tables, :mod:`.framing`
cuts tracks into frames, :mod:`.frames` holds them, :mod:`.datasets` draws synthetic scenes,
:mod:`.provenance` describes where tracks came from, :mod:`.read` recognises a file's format
and reads it into frames, :mod:`.shards` stores frames as a directory of Parquet shards)."""

from . import datasets, frames, framing, linking, provenance, read, shards, tracks

__all__ = ["datasets", "frames", "framing", "linking", "provenance", "read", "shards", "tracks"]
