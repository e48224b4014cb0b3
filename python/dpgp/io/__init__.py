"""Stage 5, files: model files (:mod:`.modelfile`), checkpoints of a running fit
(:mod:`.checkpoint`) and atomic writes (:mod:`._atomic`). Nothing here imports the estimator:
it hands this package plain state (:class:`.modelfile.ModelState`) and builds itself from a
:class:`.modelfile.ModelFile`."""

from . import checkpoint, modelfile
from ._atomic import temp_prefix
from .modelfile import FORMAT, FORMAT_VERSION, ModelFile, ModelState, parse, read_metadata, read_model_file, save

__all__ = [
    "save", "read_model_file", "parse", "ModelFile", "ModelState", "read_metadata", "FORMAT", "FORMAT_VERSION",
    "temp_prefix",
]  # fmt: skip
