"""Checkpoints of a running fit (``DPGP(checkpoint=PATH)``) and what resuming one needs
(:meth:`dpgp.DPGP.resume`).

A checkpoint IS a model file (:mod:`dpgp.io`, same archive, same checks, no pickle), so
:meth:`dpgp.DPGP.load` reads it as the model it holds. It adds the *resume point*: the state
after the last sweep that was a multiple of ``checkpoint_every`` (or after the initialisation),
from which the chain continues bitwise as the uninterrupted fit does:

==========================  ==================  ============================================
``resume_labels``           int64 (N,)          patterns of the frames at the resume point
``resume_length_scales``    float64 (K, 2)      their length scales (patterns by size)
``resume_heading_scales``   float64 (K,), opt.  their heading length scales ``w_h``: present
                                                exactly when the model file holds
                                                ``heading_scales`` (fields over heading)
metadata ``resume``         JSON object         ``sweeps_done``, ``alpha``, ``stable`` (the
                                                stopping rule's counter) and ``data_sha256``
==========================  ==================  ============================================

A checkpoint of a fit over a directory of shards (:mod:`dpgp.model.sharded`) leaves the frames
there: its ``data_sha256`` is over each shard's fingerprint and frame range
(:func:`dpgp.model.sharded.combined_fingerprint`), recorded with the directory in the file's
``shards`` entry (format version 3, :mod:`dpgp.io`), and checked against the directory before a
chain continues on it.

The model the file holds is the resume point itself while the fit runs, and the fit's final
state once it has finished (its history and ``label_trace`` then run past the resume point;
resuming truncates them to it).

Why the continuing fit re-sets its sampler at every checkpoint: a running sampler updates its
factors incrementally and names patterns by arena slot and generation (the length-scale
random streams are keyed by that id), while a sampler built from a file factors every pattern
afresh in canonical order (patterns by size, frames by index). The two states hold the same
labels, length scales and α but different rounding and ids, and the chains part at once. So at
each checkpoint the fit rebuilds its sampler from the state it writes (``set_state``), exactly
as resuming does; from there both chains are the same function of (state, seed, sweep). A fit
without checkpoints rebuilds at the same cadence (``checkpoint_every``) without writing, so
that writing checkpoints never changes the result (issue 17; the cost, under 2 % of a default
fit on US-101, is in docs/reliability.md).
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, replace
from typing import Any, TypeGuard

import numpy as np

from .._arrays import ALPHA_RANGE, MAX_MAGNITUDE, MIN_LENGTH_SCALE, alpha_in_range, as_path, is_path
from ..exceptions import InvalidInputError, ModelFileError

#: The metadata key and array names a checkpoint adds to a model file.
META_KEY = "resume"
LABELS, LENGTH_SCALES, NOISE = "resume_labels", "resume_length_scales", "resume_pattern_noise_var"
HEADING = "resume_heading_scales"
#: What ``history_`` records per sweep (a fit's and a checkpoint's).
HISTORY_KEYS = (
    "n_patterns", "alpha", "log_joint", "moves", "ari", "seconds",
    # split–merge proposals and acceptances in the sweep, and the noise pair it ended at
    "split_proposed", "split_accepted", "merge_proposed", "merge_accepted", "noise_var_x", "noise_var_y",
)  # fmt: skip


def fingerprint(frames: Any) -> str:
    """SHA-256 over the arrays the chain sees (frame offsets, positions, velocities), in a
    fixed byte order: a resumed chain must run on exactly the data it started on."""
    h = hashlib.sha256()
    for a, dtype in ((frames.offsets, "<i8"), (frames.xy, "<f8"), (frames.v, "<f8")):
        a = np.ascontiguousarray(a, dtype=dtype)
        h.update(repr(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


@dataclass(frozen=True, eq=False)
class ResumePoint:
    """The state a resumed chain starts from, after ``sweeps_done`` sweeps."""

    sweeps_done: int
    labels: np.ndarray  # (N,) int64, patterns by decreasing size
    length_scales: np.ndarray  # (K, 2)
    alpha: float
    stable: int  # sweeps the stopping rule has seen K and the ARI stable
    data_sha256: str
    pattern_noise_var: np.ndarray | None = None  # (K, 2): each pattern's noise pair (per-pattern noise)
    heading_scales: np.ndarray | None = None  # (K,): each pattern's w_h (fields over heading)

    def meta(self) -> dict[str, Any]:
        return {
            "sweeps_done": self.sweeps_done,
            "alpha": self.alpha,
            "stable": self.stable,
            "data_sha256": self.data_sha256,
        }

    def arrays(self) -> dict[str, np.ndarray]:
        return {
            LABELS: np.asarray(self.labels, dtype=np.int64),
            LENGTH_SCALES: np.asarray(self.length_scales, dtype=np.float64),
            **({} if self.pattern_noise_var is None else {NOISE: np.asarray(self.pattern_noise_var, dtype=np.float64)}),
            **({} if self.heading_scales is None else {HEADING: np.asarray(self.heading_scales, dtype=np.float64)}),
        }


def check_settings(checkpoint: Any, every: Any) -> None:
    """Types and ranges only (a model file may name a path of another machine)."""
    if checkpoint is not None and (not is_path(checkpoint) or not as_path(checkpoint)):
        raise InvalidInputError(f"checkpoint must be None or a file path, got {checkpoint!r}")
    if not (isinstance(every, (int, np.integer)) and not isinstance(every, bool) and 1 <= every <= 10**9):
        raise InvalidInputError(f"checkpoint_every must be an integer in [1, 1e9] (sweeps), got {every!r}")


def check_path(path: Any) -> str:
    """Refuse, before a fit starts or resumes, a checkpoint path that cannot be written, and
    remove the temporary files a writer killed mid-write left beside it."""
    path = as_path(path)
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        raise FileNotFoundError(f"checkpoint {path}: the directory {directory} does not exist; create it first")
    if os.path.isdir(path):
        raise IsADirectoryError(f"checkpoint {path} is a directory; give a file path")
    remove_stale_temps(path)
    return path


def remove_stale_temps(path: str) -> list[str]:
    """Remove the temporary files a writer of ``path`` killed mid-write left beside it (a
    checkpointing fit starts or resumes: nothing else writes this checkpoint)."""
    import glob

    from ._atomic import temp_prefix

    directory = os.path.dirname(os.path.abspath(path))
    stale = glob.glob(os.path.join(glob.escape(directory), glob.escape(temp_prefix(path)) + "*.tmp"))
    for name in stale:
        try:
            os.unlink(name)
        except OSError:
            pass
    return stale


def parse(meta: dict[str, Any], arrays: dict[str, np.ndarray], frames: Any, n_frames: int) -> ResumePoint | None:
    """The resume point of a checkpoint (None for a plain model file), checked against the
    file's model part and data (``frames``; None for frames left in shards, whose fingerprint
    the file records and the reader checks against the directory);
    :class:`~dpgp.ModelFileError` on any inconsistency."""
    r = meta.get(META_KEY)
    if r is None:
        return None
    if not isinstance(r, dict):
        raise ModelFileError(f"the checkpoint's {META_KEY!r} entry is not an object")
    n_iter, history = meta.get("n_iter"), meta.get("history") or {}
    done, stable, alpha = r.get("sweeps_done"), r.get("stable"), r.get("alpha")
    if not (_count(n_iter) and _count(done) and done <= n_iter):
        raise ModelFileError(
            f"the checkpoint's sweeps_done {done!r} and n_iter {n_iter!r} are not counts with sweeps_done <= n_iter"
        )
    if not (_count(stable) and stable <= done):
        raise ModelFileError(f"the checkpoint's stopping-rule counter {stable!r} is not a count <= sweeps_done")
    if not alpha_in_range(alpha):
        raise ModelFileError(
            f"the checkpoint's alpha {alpha!r} is not a number in [{ALPHA_RANGE[0]:g}, {ALPHA_RANGE[1]:g}]"
        )
    lengths = {k: len(v) for k, v in history.items()} if isinstance(history, dict) else {}
    if sorted(lengths) != sorted(HISTORY_KEYS) or any(n != n_iter for n in lengths.values()):
        raise ModelFileError(f"the checkpoint's history needs {HISTORY_KEYS} with {n_iter} entries each, has {lengths}")
    if not isinstance(meta.get("converged"), bool):
        raise ModelFileError(f"the checkpoint's converged flag {meta.get('converged')!r} is not true or false")
    trace = arrays.get("label_trace")
    if trace is None and (meta.get("settings") or {}).get("store_labels"):
        raise ModelFileError("the checkpoint of a fit with store_labels=True lacks its label_trace")
    if trace is not None and (trace.ndim != 2 or len(trace) != n_iter):
        raise ModelFileError(f"the checkpoint's label_trace has shape {trace.shape} for {n_iter} sweeps")
    labels, ls = _resume_arrays(arrays, n_frames)
    heading = heading_array(arrays, HEADING, len(ls))
    if (heading is None) != ("heading_scales" not in arrays):
        raise ModelFileError(
            f"a checkpoint holds {HEADING!r} exactly when its model holds 'heading_scales' (fields over heading)"
        )
    same = (
        alpha == meta.get("alpha")
        and np.array_equal(labels, arrays["labels"])
        and np.array_equal(ls, arrays["length_scales"])
        and (heading is None or np.array_equal(heading, arrays["heading_scales"]))
    )
    if done == n_iter and not same:
        raise ModelFileError("the checkpoint's resume point is at the model's sweep but holds another state")
    recorded = fingerprint(frames) if frames is not None else (meta.get("shards") or {}).get("data_sha256")
    if r.get("data_sha256") != recorded:
        raise ModelFileError(
            "the training data in the checkpoint do not match its fingerprint (data_sha256): the file was edited "
            "or damaged, and the chain cannot be resumed"
        )
    noise = _noise_array(arrays, NOISE, len(ls))
    return ResumePoint(int(done), labels, ls, float(alpha), int(stable), r["data_sha256"], noise, heading)  # type: ignore[arg-type]


def _noise_array(arrays: dict[str, np.ndarray], name: str, k: int) -> np.ndarray | None:
    """The optional (K, 2) per-pattern noise member ``name``, checked (None if absent)."""
    a = arrays.get(name)
    if a is None:
        return None
    a = np.asarray(a)
    if a.shape != (k, 2) or a.dtype.kind != "f" or not (np.isfinite(a).all() and (a > 0).all()):
        raise ModelFileError(f"{name} must be one positive noise pair per pattern ({k}, 2), got shape {a.shape}")
    return a.astype(np.float64)


def heading_array(arrays: dict[str, np.ndarray], name: str, k: int) -> np.ndarray | None:
    """The optional (K,) member ``name`` of heading length scales ``w_h`` (radians), checked
    (None if absent): bounded as the position length scales are."""
    a = arrays.get(name)
    if a is None:
        return None
    a = np.asarray(a)
    if a.shape != (k,) or a.dtype.kind != "f":
        raise ModelFileError(f"{name} must be one heading length scale per pattern ({k},), got shape {a.shape}")
    if not ((a >= MIN_LENGTH_SCALE).all() and (a <= MAX_MAGNITUDE).all()):
        raise ModelFileError(f"{name} must lie in [{MIN_LENGTH_SCALE:g}, {MAX_MAGNITUDE:g}]; the file is corrupted")
    return a.astype(np.float64)


def _count(x: Any) -> TypeGuard[int]:
    return isinstance(x, int) and not isinstance(x, bool) and x >= 0


def _resume_arrays(arrays: dict[str, np.ndarray], n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    if LABELS not in arrays or LENGTH_SCALES not in arrays:
        raise ModelFileError(f"the checkpoint lacks {LABELS!r} or {LENGTH_SCALES!r}")
    labels, ls = arrays[LABELS], arrays[LENGTH_SCALES]
    if (
        labels.dtype.kind not in "iu"
        or ls.dtype.kind != "f"
        or labels.shape != (n_frames,)
        or ls.ndim != 2
        or ls.shape[1:] != (2,)
    ):
        raise ModelFileError(
            f"the checkpoint's resume labels {labels.shape} and length scales {ls.shape} do not fit {n_frames} frames"
        )
    labels, ls = labels.astype(np.int64), ls.astype(np.float64)
    if len(labels) and (labels.min() < 0 or labels.max() >= len(ls) or len(np.unique(labels)) != len(ls)):
        raise ModelFileError("the checkpoint's resume labels do not name exactly its resume patterns")
    if not ((ls >= MIN_LENGTH_SCALE).all() and (ls <= MAX_MAGNITUDE).all()):
        raise ModelFileError(
            f"the checkpoint's resume length scales must lie in [{MIN_LENGTH_SCALE:g}, {MAX_MAGNITUDE:g}]"
        )
    return labels, ls


def at_resume_point(file: Any) -> Any:
    """``file`` (a :class:`dpgp.io.ModelFile` of a checkpoint) with its model state set back to the
    resume point: labels, length scales (heading length scales too) and α, history and label
    trace truncated to it."""
    p: ResumePoint = file.resume
    n = p.sweeps_done
    state = dict(file.state)
    state["history_"] = {k: list(v[:n]) for k, v in state["history_"].items()}
    state["n_iter_"], state["converged_"] = n, False
    state.pop("pattern_ids_", None)  # the model's ids; the sampler names the resume point's own
    if "label_trace_" in state:
        state["label_trace_"] = state["label_trace_"][:n]
    if state.get("draws_") is not None:  # what is kept is a function of the sweep count (dpgp.posterior)
        state["draws_"] = state["draws_"].up_to(n)
    return replace(
        file, labels=p.labels, length_scales=p.length_scales, alpha=p.alpha, state=state,
        pattern_noise_var=p.pattern_noise_var, heading_scales=p.heading_scales,
    )  # fmt: skip
