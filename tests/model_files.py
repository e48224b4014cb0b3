"""Editing saved model files for tests (tests/io/test_model_io.py, tests/generate/test_openscenario.py):
copy an archive with some members or its metadata changed."""

from __future__ import annotations

import json

import numpy as np


def _rewrite(src, dst, change) -> None:
    """Copy the archive, passing each member's arrays through ``change(name, array)``."""
    with np.load(src, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    out = {}
    for k, v in arrays.items():
        new = change(k, v)
        if new is not None:
            out[k] = new
    np.savez(dst, **out)


def _rewrite_metadata(src, dst, edit) -> None:
    """Copy the archive with ``edit(meta)`` applied to its JSON metadata (in place)."""

    def change(name, arr):
        if name != "metadata":
            return arr
        meta = json.loads(str(arr))
        edit(meta)
        return np.array(json.dumps(meta))

    _rewrite(src, dst, change)
