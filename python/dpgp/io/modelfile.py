"""Model files: a fitted :class:`~dpgp.DPGP` saved as a numpy ``.npz`` archive that executes no
code on load (``allow_pickle=False``; no pickle anywhere).

Format ``dpgp-model``, version 1. A zip archive (``numpy.savez_compressed``; every member is
CRC-checked on read) of these arrays:

==================  ======================  ===================================================
name                dtype, shape            content
==================  ======================  ===================================================
``metadata``        str, ()                 JSON, below
``frame_ids``       int, float or str (N,)  the training frames' ids
``frame_offsets``   int64 (N+1,)            row where each frame starts
``frame_xy``        float64 (n, 2)          positions, one row per vehicle observation
``frame_v``         float64 (n, 2)          velocities
``frame_labels``    (N,), optional          ground-truth labels the frames carried
``frame_tracks``    int64 (n,), optional    track id of each row (``make_frames`` keeps it)
``frame_prev_v``    float64 (n, 2), opt.    each row's previous velocity, NaN where none
``frame_prev_h…``   float64 (n,), optional  ``frame_prev_heading``: the heading carried through
                                            stops (:meth:`dpgp.Frames.headings`)
``labels``          int64 (N,)              fitted pattern of each frame (patterns by size)
``length_scales``   float64 (K, 2)          ``(w_x, w_y)`` per pattern
``pattern_ids``     uint64 (K,)             the sampler's stable pattern ids
``pattern_noise_v…``  float64 (K, 2), opt.  ``pattern_noise_var``: each pattern's noise pair
                                            (``noise_var="per_pattern"``; absent: the global pair)
``heading_scales``  float64 (K,), optional  each pattern's heading length scale ``w_h`` (radians):
                                            fields over heading (below)
``label_trace``     int64 (sweeps, N), opt.  labels per sweep (``store_labels=True``)
``draw_sweeps``     int64 (D,), optional    sweeps of the kept posterior draws (below)
``draw_labels``     int32 (D, N), optional  their labels (patterns by size within each draw)
``draw_n_patterns`` int64 (D,), optional    patterns per draw
``draw_length_s…``  float64 (ΣK, 2), opt.   ``draw_length_scales``: their length scales, draw by draw
``draw_alpha``      float64 (D,), optional  their α
``draw_heading_s…`` float64 (ΣK,), opt.     ``draw_heading_scales``: their ``w_h``, draw by draw
==================  ======================  ===================================================

The ``frame_prev_*`` members (issue 34) come with the metadata key ``frames_heading_min_speed``
(the speed, m/s, the headings were carried with). Files without them (written before them, or of
frames without tracks) load as frames without previous velocities, and older readers ignore
them and read the same model (the sampler does not use them), so they need no new version.

The ``draw_*`` members (:mod:`dpgp.posterior`) are the thinned posterior states that
posterior-averaged scores use; files without them (written before them) load with no draws, and
readers that know nothing of them read the model as before, so they need no new version.

**Fields over heading** (``DPGP(inputs="position+heading")``, issue 34): ``settings`` holds
``inputs``; the file then holds ``heading_scales``, the frames' ``frame_prev_*`` members (the
sampler's inputs), ``draw_heading_scales`` when it holds draws and, in a checkpoint,
``resume_heading_scales``; ``engine`` adds ``heading`` (``prior``, the Gamma prior of ``w_h``, and
``harmonics``, the reduced-rank basis's heading harmonics or null; ``heading_counts``, the
position functions per axis of its heading blocks, null or absent for all), the values the fit
ran with.
Each of these comes with the others: a file of fields over heading without its heading length
scales or its frames' headings, or with heading length scales but fields over position, is a
:class:`~dpgp.ModelFileError`. The format version stays 2: no reader of an earlier version
misreads such a file. Readers from before issue 34 refuse the ``inputs`` setting they do not
know; the first readers that knew it (which wrote no such model files, only checkpoints without
heading length scales) fail to rebuild the fields rather than build other ones. Files without
``inputs`` (written before it) are fields over position.

``engine`` also holds ``inputs``, the fields' input the fit ran with: ``settings`` keeps the
setting as given, which may be ``"auto"`` (``DPGP(inputs="auto")`` decides from the data, and a
loaded model must not decide again). A file whose settings say ``"auto"`` needs it; an explicit
setting must agree with it; files without it ran their setting. A reader from before ``"auto"``
refuses a file whose settings say ``"auto"`` (an unknown input) rather than misread it, and
reads the others as before, so the version stays 2.

``metadata`` holds ``format`` (``"dpgp-model"``), ``format_version``, ``dpgp_version``,
``settings`` (``DPGP.get_params()``), ``params`` (the global GP parameters), ``alpha``,
``history`` (per-sweep lists), ``n_iter``, ``converged``, ``init_seconds``, ``timings``,
``log_joint``, ``frames_summary`` (what ``make_frames`` did, with ``dt`` and ``roi``, or null)
and ``distributions`` (φ and ψ, ``EmpiricalDistributions.to_dict`` as lists, with the
pseudo-counts the scores smooth them by: ``count_pseudocount`` and ``position_pseudocount``,
keys that files before issue 36 lack, which then load as the paper's unsmoothed form, flagged by
``EmpiricalDistributions.is_paper_form``, and that older readers ignore); a model made by
``dpgp.Chains.best_model`` adds ``chain_summary`` (R̂, ESS, burn-in, the stopping verdict and the
point estimate's expected loss; ``Chains.summary_dict``). From version 2, ``resolved`` holds the
assignment, σ_n² and length-scale prior the fit ran with after ``"auto"`` and ``preset`` were
resolved (:class:`dpgp.defaults.Resolved`); version 1 files, written when those settings were
always numbers, are read by taking them from ``settings``.

A *checkpoint* (``DPGP(checkpoint=PATH)``) is a model file with a resume point besides: the
metadata key ``resume`` and the arrays ``resume_labels`` and ``resume_length_scales`` (and
``resume_heading_scales`` over heading; :mod:`dpgp.checkpoint`). Readers that know nothing of them read the model it holds.

Version 3 (written only for a checkpoint of a fit over a directory of shards): the frames stay in
their shards. The file has no ``frame_*`` members; the metadata key ``shards`` names the
directory, the frames per shard (``sizes``; ``labels`` and ``resume_labels`` are the shards'
labels one after another, in shard order) and the frames' fingerprint (``data_sha256``), which
the reader checks against the directory before it rebuilds the chain there. A version-2 reader
refuses such a file as newer rather than misreading it.

Reading (:func:`read_model_file`) checks the file and returns a :class:`ModelFile`;
:meth:`dpgp.DPGP.load` then rebuilds the sampler from the frames, labels, length scales and α
exactly as ``fit`` leaves it (every pattern factored in canonical order), so a loaded model predicts, simulates and
plots bit for bit as the saved one. A reader refuses files of a newer ``format_version``; a
writer bumps it whenever a reader of the previous version would misread the file.
"""

from __future__ import annotations

import json
import os
import tokenize
import zipfile
import zlib
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from .._arrays import ALPHA_RANGE, MIN_LENGTH_SCALE, alpha_in_range, as_path
from .._arrays import MAX_MAGNITUDE as _MAX_MAGNITUDE
from .._version import __version__
from ..exceptions import DpgpError, ModelFileError
from ._atomic import write_atomic
from .checkpoint import META_KEY as RESUME_KEY
from .checkpoint import parse as parse_resume

FORMAT = "dpgp-model"
# 2: "resolved" (what the "auto" settings and the preset resolved to); 3: frames left in shards
FORMAT_VERSION = 3
_BY_REFERENCE = 3  # the version a file of frames left in shards needs; every other file is 2

_REQUIRED = ("metadata", "labels", "length_scales")
_FRAME_MEMBERS = ("frame_ids", "frame_offsets", "frame_xy", "frame_v")


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (bytes, os.PathLike)):  # a checkpoint path among the settings
        return as_path(value)
    return value


def _ids_array(ids: np.ndarray) -> np.ndarray:
    """Frame ids as an array numpy stores without pickle (object ids become strings)."""
    ids = np.asarray(ids)
    return ids.astype(str) if ids.dtype.kind == "O" else ids


@dataclass(frozen=True, eq=False)
class ModelState:
    """What a model file stores of a fitted estimator, as plain values: the estimator builds it
    (``DPGP._file_state``) so that this package never imports the estimator."""

    settings: dict[str, Any]
    params: Any  # dpgp.gp.GPParams
    alpha: float
    n_patterns: int
    frames: Any  # dpgp.data.frames.Frames
    labels: np.ndarray
    length_scales: np.ndarray
    pattern_ids: np.ndarray
    distributions: dict[str, Any] | None  # None: frames left in shards
    motion: dict[str, Any] | None
    resolved: dict[str, Any]
    engine: dict[str, Any]
    history: dict[str, Any]
    n_iter: int | None = None
    converged: bool | None = None
    init_seconds: float | None = None
    timings: dict[str, Any] = field(default_factory=dict)
    log_joint: float | None = None
    chain_summary: dict[str, Any] | None = None
    label_trace: np.ndarray | None = None
    draws: Any = None  # dpgp.gp.draws.Draws
    transitions: dict[str, Any] | None = None  # dpgp.evaluate.transitions.Transitions.to_dict (issue 20)
    sticky: dict[str, Any] | None = None  # dynamics="sticky": {"rho": ρ, "links": frames linked to their predecessor}
    pattern_noise_var: np.ndarray | None = None  # (K, 2) under per-pattern noise
    heading_scales: np.ndarray | None = None  # (K,) w_h of fields over heading (inputs="position+heading")
    # Frames left in their shards (a checkpoint of a fit over shards): {"directory", "sizes",
    # "data_sha256"}, and ``frames`` is None.
    shards: dict[str, Any] | None = None


def save(state: ModelState, path: str | os.PathLike, resume: Any = None, compress: bool = True) -> None:
    """Write a fitted model's ``state`` to ``path`` atomically: a temporary file beside it, then
    ``os.replace``, so an interrupted or failed save leaves any previous file intact. ``resume``
    (a :class:`dpgp.io.checkpoint.ResumePoint`) makes the file a checkpoint; ``compress=False``
    stores the members uncompressed (still CRC-checked), which writes about ten times faster."""
    frames = state.frames
    summary = getattr(frames, "summary", None)
    params = state.params
    meta = {
        "format": FORMAT,
        "format_version": 2 if state.shards is None else _BY_REFERENCE,
        "dpgp_version": __version__,
        "settings": state.settings,
        "params": {
            "length_scales": params.length_scales,
            "signal_var": params.signal_var,
            "noise_var": params.noise_var,
            "mean": params.mean,
        },
        "alpha": state.alpha,
        "n_patterns": state.n_patterns,
        "history": state.history,
        "n_iter": state.n_iter,
        "converged": state.converged,
        "init_seconds": state.init_seconds,
        "timings": state.timings,
        "log_joint": state.log_joint,
        "frames_summary": None if summary is None else summary.to_dict(),
        "distributions": state.distributions,
        "motion": state.motion,  # what generation learns from the tracks
        "resolved": state.resolved,
        "engine": state.engine,
    }
    if state.chain_summary is not None:
        meta["chain_summary"] = state.chain_summary  # a model summarising chains (dpgp.fit_chains)
    if state.transitions is not None:
        meta["transitions"] = state.transitions  # optional: files before issue 20 and unordered frames lack it
    if state.sticky is not None:
        meta["sticky"] = state.sticky  # optional: only fits with dynamics="sticky" have it
    if resume is not None:
        meta[RESUME_KEY] = resume.meta()  # a checkpoint
    if state.shards is not None:
        meta["shards"] = state.shards
    if frames is not None and getattr(frames, "prev_v", None) is not None:
        meta["frames_heading_min_speed"] = frames.heading_min_speed  # with the frame_prev_* members
    arrays: dict[str, np.ndarray] = {
        "metadata": np.array(json.dumps(_jsonable(meta))),
        "labels": np.asarray(state.labels, dtype=np.int64),
        "length_scales": np.asarray(state.length_scales, dtype=np.float64),
        "pattern_ids": np.asarray(state.pattern_ids, dtype=np.uint64),
    }
    if frames is not None:
        arrays.update({
            "frame_ids": _ids_array(frames.ids),
            "frame_offsets": np.asarray(frames.offsets, dtype=np.int64),
            "frame_xy": frames.xy,
            "frame_v": frames.v,
        })  # fmt: skip
        if frames.labels is not None:
            arrays["frame_labels"] = _ids_array(frames.labels)
        if frames.tracks is not None:  # what generation learns motion from (issue 15)
            arrays["frame_tracks"] = np.asarray(frames.tracks, dtype=np.int64)
        if getattr(frames, "prev_v", None) is not None:  # each vehicle's previous step (issue 34)
            arrays["frame_prev_v"] = np.asarray(frames.prev_v, dtype=np.float64)
            arrays["frame_prev_heading"] = np.asarray(frames.prev_heading, dtype=np.float64)
    if state.pattern_noise_var is not None:
        arrays["pattern_noise_var"] = np.asarray(state.pattern_noise_var, dtype=np.float64).reshape(-1, 2)
    if state.heading_scales is not None:
        arrays["heading_scales"] = np.asarray(state.heading_scales, dtype=np.float64).reshape(-1)
    if state.label_trace is not None:
        arrays["label_trace"] = np.asarray(state.label_trace, dtype=np.int64)
    if state.draws is not None:
        arrays.update(state.draws.arrays())
    if resume is not None:
        arrays.update(resume.arrays())
    write_atomic(as_path(path), lambda fh: (np.savez_compressed if compress else np.savez)(fh, **arrays))  # type: ignore[arg-type]


def _read(path: str) -> dict[str, np.ndarray]:
    """Every array of the archive, read eagerly so that corruption surfaces here."""
    if not os.path.exists(path):
        raise FileNotFoundError(f"no such model file: {path}")
    try:
        npz = np.load(path, allow_pickle=False)
        if not isinstance(npz, np.lib.npyio.NpzFile):
            raise ModelFileError(f"{path} is a single numpy array, not a dpgp model file (.npz archive)")
        with npz:
            missing = [k for k in _REQUIRED if k not in npz.files]
            if missing:
                raise ModelFileError(f"{path} is not a dpgp model file: it lacks {missing}")
            _check_declared_sizes(path, npz.zip)  # type: ignore[arg-type]
            return {k: npz[k] for k in npz.files}
    except ModelFileError:
        raise
    except ValueError as e:
        if "pickle" in str(e):
            raise ModelFileError(
                f"{path} is not a dpgp model file: not an .npz archive (numpy would read it as pickled data, "
                "which dpgp never writes and will not load)"
            ) from None
        raise ModelFileError(f"{path} is not a dpgp model file (not a readable .npz archive): {e}") from None
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, KeyError, NotImplementedError) as e:
        raise ModelFileError(f"{path} is truncated or corrupted ({type(e).__name__}: {e})") from None
    except RuntimeError as e:  # zipfile: a member flagged as encrypted (dpgp never encrypts)
        raise ModelFileError(f"{path} is corrupted or not written by dpgp ({e})") from None
    except MemoryError:
        raise ModelFileError(f"{path} declares an array too large to read; the file is corrupted") from None


def _check_declared_sizes(path: str, archive: zipfile.ZipFile) -> None:
    """Refuse a member whose ``.npy`` header declares more data than the member holds, before
    numpy allocates it (a flipped bit in a shape asks for terabytes)."""
    fmt = np.lib.format
    for info in archive.infolist():
        with archive.open(info) as fh:
            try:
                version = fmt.read_magic(fh)
                read_header = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
                shape, _, dtype = read_header(fh, max_header_size=10_000)
            except (ValueError, SyntaxError, TypeError, tokenize.TokenError) as e:  # numpy parses it as Python
                raise ModelFileError(
                    f"{path}: member {info.filename} has an unreadable header ({e}); the file is corrupted"
                ) from None
        # Python ints: no overflow. An item of zero bytes ('V0', 'U0') still counts one: else a
        # member of 1e11 empty items reads as nothing and its conversion allocates 745 GiB.
        need = int(np.prod(shape, dtype=object)) * max(dtype.itemsize, 1)
        if need > info.file_size:
            raise ModelFileError(
                f"{path}: member {info.filename} declares shape {shape} ({need:.3g} bytes) but holds "
                f"{info.file_size} bytes; the file is corrupted"
            )


def _meta(path: str, arrays: dict[str, np.ndarray]) -> dict[str, Any]:
    raw = arrays["metadata"]
    if raw.dtype.kind != "U" or raw.shape != ():
        raise ModelFileError(f"{path}: the metadata entry is not a JSON string")
    try:
        meta = json.loads(str(raw))
    except (json.JSONDecodeError, RecursionError) as e:
        raise ModelFileError(f"{path}: the metadata is not valid JSON ({e})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise ModelFileError(
            f"{path} is not a dpgp model file (format {meta.get('format') if isinstance(meta, dict) else None!r})"
        )
    version = meta.get("format_version")
    if not isinstance(version, int) or version < 1:
        raise ModelFileError(f"{path}: invalid format_version {version!r}")
    if version > FORMAT_VERSION:
        raise ModelFileError(
            f"{path} was written by dpgp {meta.get('dpgp_version', '?')} in model-file format version {version}; "
            f"this dpgp reads versions up to {FORMAT_VERSION}: upgrade dpgp to load it"
        )
    return meta


def read_metadata(path: str | os.PathLike) -> dict[str, Any]:
    """The JSON metadata of a model file (format, versions, settings, history, φ/ψ), checked
    like :func:`load` does but without rebuilding the model."""
    path = as_path(path)
    return _meta(path, _read(path))


@dataclass(frozen=True, eq=False)
class ModelFile:
    """What a model file holds, read and checked: :meth:`dpgp.DPGP.load` builds the estimator
    from it (this module takes nothing from the estimator but its public attributes).

    ``state`` holds the fitted attributes restored as saved (``pattern_ids_``, ``history_``,
    ``n_iter_``, ``converged_``, ``init_seconds_``, ``timings_`` and, where present,
    ``label_trace_`` and ``chain_summary_``). ``resume`` is a checkpoint's resume point
    (:class:`dpgp.checkpoint.ResumePoint`), None for a plain model file."""

    path: str
    settings: dict[str, Any]
    frames: Any
    labels: np.ndarray
    length_scales: np.ndarray
    alpha: float
    params: Any
    resolved: Any
    likelihood: str
    basis: Any
    state: dict[str, Any]
    distributions: Any
    resume: Any = None
    motion: Any = None  # a dpgp.motion.MotionModel; None in files written before issue 15
    transitions: Any = None  # a dpgp.evaluate.transitions.Transitions; None before issue 20 or without times
    sticky: dict[str, Any] | None = None  # ρ and the linked frames under dynamics="sticky"
    pattern_noise_var: np.ndarray | None = None  # (K, 2): each pattern's noise pair (per-pattern noise)
    sampler: str = "collapsed"  # the sampler that ran the chain; files before issue 32 ran the collapsed one
    shards: dict[str, Any] | None = None  # frames left in shards: directory, sizes, data_sha256 (frames is None)
    heading_scales: np.ndarray | None = None  # (K,): each pattern's w_h (fields over heading)
    heading: dict[str, Any] | None = None  # the w_h prior and heading harmonics the fit ran with (None: the defaults)
    inputs: str = "position"  # the fields' input the fit ran with (settings' "auto" resolved)


def read_model_file(path: str | os.PathLike) -> ModelFile:
    """Read and check a model written by :func:`save`; :class:`~dpgp.ModelFileError` if the
    file is truncated, corrupted, not a model file, of a newer format version or inconsistent."""
    path = as_path(path)
    arrays = _read(path)
    return parse(_meta(path, arrays), arrays, path)


def parse(meta: dict[str, Any], arrays: dict[str, np.ndarray], path: str = "model") -> ModelFile:
    """A :class:`ModelFile` from the metadata and arrays of a model file."""
    try:
        return _parse(meta, arrays, path)
    except ModelFileError:
        raise
    except (DpgpError, KeyError, TypeError, ValueError, IndexError, AttributeError) as e:
        raise ModelFileError(f"{path}: inconsistent model file ({type(e).__name__}: {e})") from None


def _parse(meta: dict[str, Any], arrays: dict[str, np.ndarray], path: str) -> ModelFile:
    from ..data.frames import Frames

    settings = {k: tuple(v) if isinstance(v, list) else v for k, v in meta["settings"].items()}
    shards = _shards(meta)
    if shards is not None:
        return _parse_rest(meta, arrays, path, settings, None, sum(shards["sizes"]), shards)
    missing = [k for k in _FRAME_MEMBERS if k not in arrays]
    if missing:
        raise ModelFileError(f"{path} is not a dpgp model file: it lacks {missing}")
    _check_counts(arrays, arrays["frame_xy"].size // 2)
    _check_finite(arrays)
    labels_file = arrays.get("frame_labels")
    prev_v, prev_h = arrays.get("frame_prev_v"), arrays.get("frame_prev_heading")
    if (prev_v is None) != (prev_h is None):
        raise ModelFileError(f"{path}: frame_prev_v and frame_prev_heading come together; the file is corrupted")
    frames = Frames(
        arrays["frame_ids"],
        arrays["frame_offsets"],
        arrays["frame_xy"],
        arrays["frame_v"],
        labels_file,
        arrays.get("frame_tracks"),
        prev_v,
        prev_h,
        meta.get("frames_heading_min_speed") if prev_v is not None else None,
    )
    return _parse_rest(meta, arrays, path, settings, frames, len(frames), None)


def _parse_rest(
    meta: dict[str, Any],
    arrays: dict[str, np.ndarray],
    path: str,
    settings: dict[str, Any],
    frames: Any,
    n_frames: int,
    shards: dict[str, Any] | None,
) -> ModelFile:
    """The model part of a model file, over ``frames`` (None: ``n_frames`` frames left in
    ``shards``)."""
    from ..data.framing import FramingSummary
    from ..evaluate.transitions import Transitions
    from ..generate.distributions import EmpiricalDistributions
    from ..generate.motion import MotionModel
    from ..gp.draws import Draws
    from ..gp.exact import GPParams, check_scales

    if frames is None:
        _check_counts(arrays, n_frames)
    elif meta.get("frames_summary") is not None:
        known = {f.name for f in fields(FramingSummary)}  # a newer writer's extra keys are ignored
        s = {k: v for k, v in meta["frames_summary"].items() if k in known}
        for key in ("roi", "smoothing", "object_size"):
            if s.get(key) is not None:
                s[key] = tuple(s[key])
        frames.summary = FramingSummary(**s)
    labels = np.asarray(arrays["labels"], dtype=np.int64)
    ls = np.asarray(arrays["length_scales"], dtype=np.float64)
    if labels.shape != (n_frames,) or ls.ndim != 2 or ls.shape[1] != 2:
        raise ModelFileError(f"labels {labels.shape} and length_scales {ls.shape} do not fit {n_frames} frames")
    if len(labels) and (labels.min() < 0 or labels.max() >= len(ls) or len(np.unique(labels)) != len(ls)):
        raise ModelFileError("labels do not name exactly the patterns the file holds")
    _check_numbers(frames, ls, meta["alpha"])
    p = meta["params"]
    params = GPParams(tuple(p["length_scales"]), tuple(p["signal_var"]), p["noise_var"], tuple(p["mean"]))
    try:
        # Frames left in shards: the velocities' scale is checked where they are (the shards are
        # fingerprinted against the file before a chain runs on them).
        check_scales(np.zeros((0, 2)) if frames is None else frames.v, params, "frame_v")
    except DpgpError as e:
        raise ModelFileError(
            f"the model's numbers are beyond what a fit accepts ({e}); the file is corrupted"
        ) from None
    likelihood, basis = _engine(meta)
    inputs = _inputs(meta, settings)
    heading_scales, heading = _heading(meta, arrays, inputs, frames, len(ls), likelihood)
    history = {k: list(v) for k, v in meta.get("history", {}).items()}
    for key, values in history.items():
        if not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in values):
            raise ModelFileError(f"the history's {key!r} holds values that are not numbers")
    state: dict[str, Any] = {
        "history_": history,
        "n_iter_": meta.get("n_iter"),
        "converged_": meta.get("converged"),
        "init_seconds_": meta.get("init_seconds"),
        "timings_": dict(meta.get("timings") or {}),
    }
    if "pattern_ids" in arrays and len(arrays["pattern_ids"]) == len(ls):
        state["pattern_ids_"] = np.asarray(arrays["pattern_ids"], dtype=np.uint64)
    if "label_trace" in arrays:
        state["label_trace_"] = np.asarray(arrays["label_trace"], dtype=np.int64)
    if meta.get("chain_summary") is not None:
        state["chain_summary_"] = meta["chain_summary"]
    draws = Draws.from_arrays(arrays, n_frames, MIN_LENGTH_SCALE, _MAX_MAGNITUDE)  # None: a file before them
    if draws is not None:
        if len(draws) and (heading_scales is None) != ("draw_heading_scales" not in arrays):
            raise ModelFileError(
                "the posterior draws hold heading length scales exactly when the model does (fields over heading)"
            )
        state["draws_"] = draws
    if isinstance((meta.get("engine") or {}).get("choice"), dict):
        state["engine_choice_"] = meta["engine"]["choice"]
    d = meta.get("distributions")
    tr = meta.get("transitions")
    transitions = None if tr is None else Transitions.from_dict(tr, len(ls))
    return ModelFile(
        path, settings, frames, labels, ls, float(meta["alpha"]), params, _resolved(meta), likelihood, basis, state,
        None if d is None else EmpiricalDistributions.from_dict(d), parse_resume(meta, arrays, frames, n_frames),
        None if meta.get("motion") is None else MotionModel.from_dict(meta["motion"]), transitions,
        _sticky(meta.get("sticky"), n_frames), _pattern_noise(arrays, len(ls)), _sampler(meta), shards,
        heading_scales, heading, inputs,
    )  # fmt: skip


def _shards(meta: dict[str, Any]) -> dict[str, Any] | None:
    """The ``shards`` entry of a file whose frames were left in shards, checked (None if absent)."""
    s = meta.get("shards")
    if s is None:
        return None
    ok = (
        isinstance(s, dict)
        and isinstance(s.get("directory"), str)
        and isinstance(s.get("sizes"), list)
        and len(s["sizes"]) >= 1
        and all(isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in s["sizes"])
        and isinstance(s.get("data_sha256"), str)
        and len(s["data_sha256"]) == 64
    )
    if not ok:
        raise ModelFileError("the 'shards' entry needs a directory, the frames per shard (sizes) and data_sha256")
    if meta.get("format_version", 0) < _BY_REFERENCE:
        raise ModelFileError(f"a file of frames left in shards needs format_version {_BY_REFERENCE}; it is corrupted")
    return {"directory": s["directory"], "sizes": list(s["sizes"]), "data_sha256": s["data_sha256"]}


def _pattern_noise(arrays: dict[str, np.ndarray], k: int) -> np.ndarray | None:
    from .checkpoint import _noise_array

    return _noise_array(arrays, "pattern_noise_var", k)


def _sticky(value: Any, n_frames: int) -> dict[str, Any] | None:
    """The stored ρ and links of a dynamics="sticky" fit, checked (None when absent)."""
    if value is None:
        return None
    rho, links = (value.get("rho"), value.get("links")) if isinstance(value, dict) else (None, None)
    if not (isinstance(rho, float) and 0 < rho < 1 and isinstance(links, list)) or not all(
        isinstance(t, int) and not isinstance(t, bool) and 0 <= t < n_frames for t in links
    ):
        raise ModelFileError("the sticky prior's stored rho or links are not valid")
    return {"rho": rho, "links": links}


def _check_counts(arrays: dict[str, np.ndarray], n_rows: int) -> None:
    """Refuse, before any conversion allocates, arrays whose items are not numbers or text or
    take no bytes (a declared shape of 1e11 empty items converts to 745 GiB of int64), and
    per-frame members longer than the ``n_rows`` vehicle observations (frames in shards: frames)."""
    for name, a in arrays.items():
        if not isinstance(a, np.ndarray) or a.dtype.kind not in "biufU" or (a.size and a.dtype.itemsize == 0):
            raise ModelFileError(
                f"member {name!r} holds {getattr(a, 'dtype', type(a).__name__)} items, not numbers or text"
            )
    for name in ("frame_ids", "frame_offsets", "labels", "frame_labels", "resume_labels"):
        if name in arrays and arrays[name].size > n_rows + 1:
            raise ModelFileError(f"member {name!r} has {arrays[name].size} entries for {n_rows} vehicle observations")
    if "label_trace" in arrays and arrays["label_trace"].size > (n_rows + 1) * 10**7:
        raise ModelFileError(f"member 'label_trace' has {arrays['label_trace'].size} entries; the file is corrupted")


def _check_finite(arrays: dict[str, np.ndarray]) -> None:
    """NaN or inf among the stored positions or velocities means a damaged file (a fit refuses
    them): say so before :class:`~dpgp.Frames` refuses them as bad input."""
    for name in ("frame_v", "frame_xy"):
        a = arrays[name]
        if a.dtype.kind == "f" and not np.isfinite(a).all():
            raise ModelFileError(f"{name} holds NaN or inf; the file is corrupted")


def _check_numbers(frames: Any, length_scales: np.ndarray, alpha: Any) -> None:
    """The numbers a fit would have refused (magnitudes past 1e100, α or length scales <= 0;
    NaN and inf: :func:`_check_finite`) mean a damaged file: refuse them here rather than load
    a model that gives NaN."""
    for name, a in () if frames is None else (("frame_v", frames.v), ("frame_xy", frames.xy)):
        with np.errstate(over="ignore", invalid="ignore"):  # a mean of 1e308s overflows: also too large
            size = float(np.max(np.abs(a - a.mean(axis=0)) if name == "frame_xy" else np.abs(a))) if len(a) else 0.0
        if not size <= _MAX_MAGNITUDE:
            raise ModelFileError(
                f"{name} holds values of magnitude {size:.3g}, beyond the {_MAX_MAGNITUDE:g} a fit accepts; the file is corrupted"
            )
    # Squared length scales must stay normal floats; a fit never comes near these bounds.
    if not ((length_scales >= MIN_LENGTH_SCALE).all() and (length_scales <= _MAX_MAGNITUDE).all()):
        raise ModelFileError(
            f"length_scales must lie in [{MIN_LENGTH_SCALE:g}, {_MAX_MAGNITUDE:g}]; the file is corrupted"
        )
    if not alpha_in_range(alpha):
        raise ModelFileError(
            f"alpha must be a number in [{ALPHA_RANGE[0]:g}, {ALPHA_RANGE[1]:g}], got {alpha!r}; the file is corrupted"
        )


def _engine(meta: dict[str, Any]) -> tuple[str, Any]:
    """The likelihood that ran and its basis (files written before reduced-rank fits existed ran
    the exact likelihood). The memory budget is the loading machine's: the estimator sets it."""
    from ..gp.hsgp import Basis

    e = meta.get("engine") or {"likelihood": "exact", "basis": None, "memory_budget": None}
    if e.get("likelihood") not in ("exact", "hsgp") or (e["likelihood"] == "hsgp") != (e.get("basis") is not None):
        raise ModelFileError(f"unknown likelihood or basis in the model file: {e!r}")
    return e["likelihood"], None if e.get("basis") is None else Basis.from_dict(e["basis"])


def _inputs(meta: dict[str, Any], settings: dict[str, Any]) -> str:
    """The fields' input the fit ran with: the engine entry's ``inputs`` (written since
    ``inputs="auto"``), which must agree with an explicit setting; files without it ran the
    setting (``"position"`` before the setting existed)."""
    given = settings.get("inputs", "position")
    ran = (meta.get("engine") or {}).get("inputs", None if given == "auto" else given)
    if ran not in ("position", "position+heading"):
        raise ModelFileError(
            f"the engine's inputs {ran!r} (settings: {given!r}) is not a fields' input the fit can have run with "
            "('position' or 'position+heading'); the file is corrupted"
        )
    if given != "auto" and ran != given:
        raise ModelFileError(f"the settings give inputs={given!r} but the engine ran {ran!r}; the file is corrupted")
    return ran


def _heading(
    meta: dict[str, Any], arrays: dict[str, np.ndarray], inputs: str, frames: Any, k: int, likelihood: str
) -> tuple[np.ndarray | None, dict[str, Any] | None]:
    """Fields over heading: each pattern's ``w_h`` and the engine's heading entry (the prior and
    harmonics the fit ran with; None in a file without it), checked against the fields' input
    (:func:`_inputs`) and the frames; ``(None, None)`` for fields over position."""
    from .checkpoint import heading_array

    headed = inputs == "position+heading"
    scales = heading_array(arrays, "heading_scales", k)
    if scales is not None and not headed:
        raise ModelFileError(
            f"the file holds heading length scales but its fields are over {inputs!r}, "
            "not 'position+heading'; it is corrupted"
        )
    if not headed:
        if "heading" in (meta.get("engine") or {}):
            raise ModelFileError(
                "the engine has a heading entry but the fields are over position; the file is corrupted"
            )
        return None, None
    if scales is None:
        raise ModelFileError(
            "the file's fields are over position and heading (inputs='position+heading') but it holds no heading "
            "length scales ('heading_scales'): it was not written by a dpgp that saves such models, or it is damaged"
        )
    # A checkpoint whose frames stay in their shards (frames None): the shards carry the headings.
    if frames is not None and getattr(frames, "prev_heading", None) is None:
        raise ModelFileError(
            "the file holds heading length scales (fields over heading) but not its frames' previous headings "
            "('frame_prev_heading'), which the fields take as input; the file is corrupted"
        )
    h = (meta.get("engine") or {}).get("heading")
    if h is None:
        return scales, None
    prior, harmonics, counts = (
        (h.get("prior"), h.get("harmonics"), h.get("heading_counts")) if isinstance(h, dict) else (None, None, None)
    )
    prior_ok = (
        isinstance(prior, list)
        and len(prior) == 2
        and all(isinstance(x, (int, float)) and not isinstance(x, bool) and 0 < x < _MAX_MAGNITUDE for x in prior)
    )
    # The core bounds the basis the harmonics make; here only a count it can take.
    count = isinstance(harmonics, int) and not isinstance(harmonics, bool) and 0 <= harmonics <= 10**6
    harmonics_ok = harmonics is None if likelihood == "exact" else count
    # The heading blocks' position counts: absent or null (every position function, as files
    # before them), else two positive counts (the core checks them against the basis).
    counts_ok = counts is None or (
        likelihood != "exact"
        and isinstance(counts, list)
        and len(counts) == 2
        and all(isinstance(x, int) and not isinstance(x, bool) and 0 < x <= 10**6 for x in counts)
    )
    if not (prior_ok and harmonics_ok and counts_ok):
        raise ModelFileError(
            f"the engine's heading entry {h!r} needs a prior of two positive numbers and, for the hsgp likelihood "
            "only, a count of harmonics and optionally two heading counts; the file is corrupted"
        )
    return scales, {
        "prior": (float(prior[0]), float(prior[1])),  # type: ignore[index]
        "harmonics": harmonics,
        "heading_counts": None if counts is None else (int(counts[0]), int(counts[1])),
    }


def _sampler(meta: dict[str, Any]) -> str:
    """The sampler that ran the chain ("collapsed" in files written before the sub-cluster sampler)."""
    sampler = (meta.get("engine") or {}).get("sampler", "collapsed")
    if sampler not in ("collapsed", "subcluster"):
        raise ModelFileError(f"unknown sampler in the model file: {sampler!r}")
    if sampler == "subcluster" and (meta.get("engine") or {}).get("likelihood") != "hsgp":
        raise ModelFileError("the model file says the sub-cluster sampler ran without the hsgp likelihood")
    return sampler


def _resolved(meta: dict[str, Any]) -> Any:
    """The assignment, σ_n² and length-scale prior the fit resolved (never re-estimated: the
    saved model is what was fitted)."""
    from ..gp.defaults import Resolved, _gamma, _positive_pair

    r = meta.get("resolved")
    if r is None:  # version 1: the settings were the values
        s = meta["settings"]
        r = {
            "assignment": s["assignment"], "noise_var": s["noise_var"],
            "length_scale_prior": s["length_scale_prior"], "noise_var_source": "user", "length_scale_prior_source": "user",
        }  # fmt: skip
    scores = r.get("noise_scores")
    return Resolved(**{
        **r, "length_scale_prior": _gamma("length_scale_prior", r["length_scale_prior"]),  # a fit's own limits
        "noise_var": _positive_pair("noise_var", r["noise_var"]),  # files before per-component noise: one number
        "noise_scores": None if scores is None else tuple(tuple(float(x) for x in row) for row in scores),
    })  # fmt: skip


__all__ = ["save", "ModelState", "read_model_file", "parse", "ModelFile", "read_metadata", "FORMAT", "FORMAT_VERSION"]
