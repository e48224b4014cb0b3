"""Many independent chains of the DP-GP sampler, on local worker processes or on a Dask cluster,
with multi-chain convergence diagnostics and one summary partition.

How a run is organised (the why):

- A chain advances in *blocks* of sweeps; each block is one task, a pure function of (frames,
  settings, the chain's state after the previous block, a seed). The state is plain data: the
  labels, each pattern's length scales, α and the GP parameters. A block that continues a chain
  rebuilds the sampler at that state (what loading a model file does) and sweeps on. Because
  the collapsed sampler's state *is* (labels, length scales, α), this is the same Markov chain
  as one long fit; only its random numbers come from a fresh stream per block.
- The seed of chain c's block b is derived from ``seed`` by ``SeedSequence(seed, spawn_key=(c,
  b))``: adding chains or workers, or moving from local processes to Dask, changes nothing.
- The stopping rule is checked on the driver between rounds of blocks (all chains the same
  length), so tasks never wait on each other and a chain's state always lives on the driver,
  where a crashed worker cannot take it.
- Engines: ``client=None`` runs blocks on a ``ProcessPoolExecutor`` of spawned processes that
  receive the frames once, at start-up; a ``dask.distributed.Client`` runs them on its cluster,
  the frames scattered to it once and passed to every task by reference. Dask retries a task
  whose worker died up to its ``distributed.scheduler.allowed-failures`` setting; beyond that
  (or when the chain itself raises) the chain is reported by name in ``Chains.failures_`` and
  the others carry on.
"""

from __future__ import annotations

import concurrent.futures as cf
import os
import signal
import time
import uuid
import warnings
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..data.frames import Frames, as_frames
from ..exceptions import DpgpError, InvalidInputError
from . import diagnostics, partition
from ._interrupt import Interrupts, WorkerContext, mark

QUANTITIES = ("log_joint", "n_patterns", "alpha")
_TRACES = (*QUANTITIES, "moves", "seconds")
# Settings that fit_chains controls itself; the rest pass through to DPGP.
_RESERVED = ("iterations", "seed", "progress", "store_labels", "n_iter_no_change")
# How often the driver, waiting for tasks, looks for a Ctrl-C that came while it was not waiting
# (_interrupt), and how long it waits for a block that finished on a cluster as Ctrl-C came.
_POLL_SECONDS = 0.2
_FETCH_SECONDS = 2.0


class ChainsFailedError(DpgpError):
    """Every chain failed; the message names each chain and its error."""


# --- the task: one block of sweeps of one chain ----------------------------------------------
@dataclass
class _State:
    """A chain's state between blocks (plain data; pickles cheaply)."""

    labels: np.ndarray  # (N,) int64, patterns by decreasing size
    length_scales: np.ndarray  # (K, 2)
    alpha: float
    params: dict[str, Any]  # the GP parameters fit derived from the frames
    resolved: dict[str, Any] | None  # "auto" settings as the first block resolved them
    # The likelihood and basis the first block chose (likelihood="auto"): every later block
    # must sample the same model.
    engine: dict[str, Any] | None = None
    pattern_noise_var: np.ndarray | None = None  # (K, 2) under per-pattern noise


@dataclass
class _Block:
    """What a block returns: per-sweep traces and labels, and the state it ends in."""

    traces: dict[str, np.ndarray]
    labels: np.ndarray  # (sweeps, N) int32, canonical per sweep
    state: _State


_WORKER_FRAMES: Frames | None = None


def _init_worker(frames: Frames) -> None:
    """Local worker start-up: keep the frames; leave Ctrl-C to the driver, which cancels (the
    worker was spawned with SIGINT blocked; ignoring it also drops one that is pending)."""
    global _WORKER_FRAMES
    _WORKER_FRAMES = frames
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _task(key: str, fn: Any, *args: Any) -> Any:
    """Run one task (a block, or resolving the settings) on a worker; its start is a trace event."""
    mark(f"task {key} start")
    return fn(*args)


def _state_of(model: Any) -> _State:
    p = model.params_
    params = {"length_scales": p.length_scales, "signal_var": p.signal_var, "noise_var": p.noise_var, "mean": p.mean}
    # What the "auto" settings resolved to on the data (dpgp.defaults): later blocks and the
    # point-estimate model are rebuilt with these values, never by estimating them again.
    defaults = getattr(model, "defaults_", None)
    resolved = None if defaults is None else defaults.to_dict()
    engine = model.engine_info()
    noise = model.pattern_noise_var_.copy() if model._per_pattern_noise() else None
    return _State(
        model.labels_.copy(), model.length_scales_.copy(), float(model.alpha_), params, resolved, engine, noise
    )


def _model_at(frames: Any, settings: dict[str, Any], state: _State, extra_meta: dict[str, Any] | None = None) -> Any:
    """A fitted DPGP at ``state``, rebuilt the way a model file is loaded (dpgp.io), so that it
    predicts, simulates and saves like any fitted model; over the shards of ``frames`` when it is
    the chains' :class:`~dpgp.model.sharded.ShardSource`."""
    from .. import io
    from ..model.estimator import DPGP
    from ..model.sharded import ShardSource

    if isinstance(frames, ShardSource):
        return _model_over_shards(frames, settings, state, extra_meta)

    summary = getattr(frames, "summary", None)
    meta = {
        "settings": settings,
        "resolved": state.resolved,
        "params": state.params,
        "alpha": state.alpha,
        "engine": state.engine,
        "frames_summary": None if summary is None else summary.to_dict(),
        **(extra_meta or {}),
    }
    arrays = {
        "frame_ids": frames.ids,
        "frame_offsets": frames.offsets,
        "frame_xy": frames.xy,
        "frame_v": frames.v,
        **_state_arrays(state),
    }
    if frames.labels is not None:
        arrays["frame_labels"] = frames.labels
    return DPGP.from_model_file(io.parse(meta, arrays))


def _state_arrays(state: _State) -> dict[str, np.ndarray]:
    """The model-file members of a chain's state (labels, length scales, per-pattern noise)."""
    arrays = {
        "labels": np.asarray(state.labels, dtype=np.int64),
        "length_scales": np.asarray(state.length_scales, dtype=np.float64).reshape(-1, 2),
    }
    if state.pattern_noise_var is not None:
        arrays["pattern_noise_var"] = np.asarray(state.pattern_noise_var, dtype=np.float64).reshape(-1, 2)
    return arrays


def _model_over_shards(source: Any, settings: dict[str, Any], state: _State, extra: dict[str, Any] | None) -> Any:
    """:func:`_model_at` for chains over shards: a file of frames left in shards (dpgp.io, version
    3) whose chain runs over the chains' shared ``source``."""
    from .. import io
    from ..model.estimator import DPGP

    shards = {"directory": source.directory, "sizes": source.sizes, "data_sha256": source.sample(fingerprint=True)[2]}
    meta = {
        "format_version": 3, "settings": settings, "resolved": state.resolved, "params": state.params,
        "alpha": state.alpha, "engine": state.engine, "shards": shards, **(extra or {}),
    }  # fmt: skip
    return DPGP.from_model_file(io.parse(meta, _state_arrays(state)), source=source)


def _run_block(frames: Any, settings: dict[str, Any], seed: int, state: _State | None, sweeps: int) -> _Block:
    """Run ``sweeps`` sweeps of a chain from ``state`` (None: initialise) with ``seed``: a fit,
    or the model at ``state`` continued by ``fit(warm_start=True)`` (the one sweep loop)."""
    from ..model.estimator import DPGP

    frames = _WORKER_FRAMES if frames is None else frames
    assert frames is not None
    run = {**settings, "seed": seed, "progress": False, "iterations": sweeps, "store_labels": True}
    model = DPGP(**run) if state is None else _model_at(frames, run, state)
    model._keep_state_on_interrupt = False  # a block stopped part-way is no block (fit_chains' threads)
    model.fit(frames, warm_start=state is not None)
    h = model.history_
    traces = {name: np.asarray(h[name][-sweeps:], dtype=float) for name in _TRACES}
    return _Block(traces, model.label_trace_[-sweeps:].astype(np.int32), _state_of(model))


def _resolve(frames: Frames | None, settings: dict[str, Any], seed: int) -> tuple[dict[str, Any] | None, str, str]:
    """What the "auto" settings resolve to on the frames (a fit with no sweeps resolves them),
    or None where the model has nothing to resolve, the likelihood (``"auto"`` decides it by
    predicted cost, dpgp.engine_cost) and the sampler. Run once per fit_chains, so that every
    chain samples the same model with the same sampler."""
    from ..model.estimator import DPGP

    frames = _WORKER_FRAMES if frames is None else frames
    model = DPGP(**{**settings, "seed": seed, "progress": False}, iterations=0).fit(frames)
    defaults = getattr(model, "defaults_", None)
    return (None if defaults is None else defaults.to_dict()), model.likelihood_, model.sampler_


def _explicit(settings: dict[str, Any], resolved: dict[str, Any] | None) -> dict[str, Any]:
    """``settings`` with the resolved values in place of "auto" (and no preset)."""
    if resolved is None:
        return settings
    # A noise sampled inside the chain stays "auto": each chain samples it (resolving it costs nothing).
    keys = ("assignment", "length_scale_prior") + (
        () if resolved.get("noise_var_source") in ("sampled", "per_pattern") else ("noise_var",)
    )
    out = {**settings, **{k: resolved[k] for k in keys}}
    out["length_scale_prior"] = tuple(out["length_scale_prior"])
    if "preset" in settings:
        out["preset"] = None
    return out


def block_seed(seed: int, chain: int, block: int) -> int:
    """The seed of a chain's block: independent streams per (seed, chain, block)."""
    return int(np.random.SeedSequence(seed, spawn_key=(chain, block)).generate_state(1, np.uint64)[0])


# --- engines: where the blocks run -------------------------------------------------------------
class _Futures:
    """Waiting on ``concurrent.futures`` (the local engines' futures)."""

    def wait(self, futures: list[Any], timeout: float) -> set[Any]:
        return cf.wait(futures, timeout=timeout, return_when=cf.FIRST_COMPLETED)[0]

    def finished(self, future: cf.Future) -> Any:
        """The result of a task that has finished without error, else None."""
        ok = future.done() and not future.cancelled() and future.exception() is None
        return future.result() if ok else None


class _LocalEngine(_Futures):
    """Spawned worker processes (fork is unsafe once the core's thread pool exists)."""

    def __init__(self, frames: Frames, n_workers: int) -> None:
        self.frames, self.n_workers = frames, n_workers
        self.pool = self._new_pool()

    def _new_pool(self) -> cf.ProcessPoolExecutor:
        ctx = WorkerContext()  # "spawn", workers deaf to Ctrl-C from birth
        return cf.ProcessPoolExecutor(self.n_workers, mp_context=ctx, initializer=_init_worker, initargs=(self.frames,))

    def submit(self, key: str, fn: Any, *args: Any) -> cf.Future:
        return self.pool.submit(_task, key, fn, None, *args)

    def broken(self, error: BaseException) -> bool:
        """A worker process died: every block in flight failed with it; start a fresh pool."""
        if isinstance(error, cf.process.BrokenProcessPool):
            self.pool.shutdown(wait=False, cancel_futures=True)
            self.pool = self._new_pool()
            return True
        return False

    def cancel(self, futures: list[Any]) -> None:
        for f in futures:
            f.cancel()
        # Running blocks cannot be cancelled; stop their processes.
        terminate = getattr(self.pool, "terminate_workers", None)  # Python >= 3.14
        if terminate is not None:
            terminate()
        else:
            for p in list(getattr(self.pool, "_processes", {}).values()):
                p.terminate()
        # A worker stopped while sending its result leaves half a message in the result pipe, and
        # the pool's manager thread would wait for the rest forever (and shutdown with it, and the
        # interpreter at exit). With the driver's copy of the pipe's write end closed, the stopped
        # workers held the last ones: the thread reads end-of-file and gives up.
        queue = getattr(self.pool, "_result_queue", None)
        if queue is not None:
            queue._writer.close()

    def close(self) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)


class _DaskEngine:
    """A dask.distributed Client: the frames scattered once, one task per block."""

    def __init__(self, client: Any, frames: Frames) -> None:
        self.client = client
        self.frames = client.scatter(frames, hash=False)
        self.run = uuid.uuid4().hex[:8]

    def submit(self, key: str, fn: Any, *args: Any) -> Any:
        return self.client.submit(
            _task, key, fn, self.frames, *args, key=f"dpgp-{key}-{self.run}", pure=False, retries=0
        )

    def wait(self, futures: list[Any], timeout: float) -> set[Any]:
        from distributed import wait

        try:
            return set(wait(futures, timeout=timeout, return_when="FIRST_COMPLETED").done)
        except TimeoutError:
            return set()

    def finished(self, future: Any) -> Any:
        """The result of a task that has finished without error, else None; not waiting long for
        it (its worker may have taken the same Ctrl-C and gone)."""
        if future.status != "finished":
            return None
        try:
            return future.result(timeout=_FETCH_SECONDS)
        except Exception:  # noqa: BLE001 - lost with its worker: not a finished block after all
            return None

    def broken(self, error: BaseException) -> bool:
        return False  # Dask reschedules on its own; an error here belongs to one chain

    def cancel(self, futures: list[Any]) -> None:
        self.client.cancel(list(futures))

    def close(self) -> None:
        self.client.cancel([self.frames])


class _ThreadEngine(_Futures):
    """Chains over shards (:class:`~dpgp.model.sharded.ShardSource`): each block runs in a thread
    of this process, the chain's leader, and its frames' work goes to the shards (read into this
    process once, or served by a Dask client's workers), shared by every chain. The leaders'
    sweeps run with the GIL released and wait on the shards, so the chains overlap."""

    def __init__(self, source: Any, n_chains: int) -> None:
        self.source = source
        self.pool = cf.ThreadPoolExecutor(max(1, n_chains), thread_name_prefix="dpgp-chain")

    def submit(self, key: str, fn: Any, *args: Any) -> cf.Future:
        return self.pool.submit(_task, key, fn, self.source, *args)

    def broken(self, error: BaseException) -> bool:
        return False  # no worker process to lose here; a shard's worker is Dask's to replace

    def cancel(self, futures: list[Any]) -> None:
        for f in futures:
            f.cancel()
        self.source.stopping.set()  # running blocks stop before their next sweep

    def close(self) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)
        self.source.stopping.clear()
        self.source.close()  # the workers drop the shards; the chains' models load them again if asked


# --- the driver --------------------------------------------------------------------------------
def fit_chains(
    frames: Frames | Any,
    n_chains: int = 4,
    client: Any = None,
    *,
    iterations: int = 100,
    until: str | None = None,
    rhat: float = 1.01,
    min_ess: float = 400,
    max_iterations: int = 2000,
    max_seconds: float | None = None,
    block: int | None = None,
    burn_in: int | None = None,
    seed: int = 0,
    n_workers: int | None = None,
    progress: bool = True,
    init: str = "sequential",
    **settings: Any,
) -> Chains:
    """Fit ``n_chains`` independent chains of :class:`dpgp.DPGP` and return them as :class:`Chains`.

    Parameters
    ----------
    frames : training frames (:class:`dpgp.Frames` or a framed DataFrame), or a directory of
        shards (:meth:`dpgp.Frames.to_parquet`). With a directory and settings that run over
        shards (as :meth:`dpgp.DPGP.fit` decides) every chain runs over the shards: its leader in
        a thread of this process, the shards read into this process once (``client=None``) or
        each loaded once by a worker of ``client``'s cluster and shared by the chains (chains ×
        shards tasks a round of requests). The same seed and shards give the same chains either
        way. Other settings read the directory into memory.
    client : ``None`` runs the chains on local worker processes (``n_workers``, default one per
        chain up to the number of cores); a ``dask.distributed.Client`` runs one task per chain
        and block on its cluster (``pip install dpgp[distributed]``), or serves the shards.
    iterations : sweeps per chain when ``until`` is None.
    until : ``"converged"`` advances all chains ``block`` sweeps at a time until, over the
        second half of the sweeps, the rank-normalised split-R̂ of the log joint, K and α is at
        most ``rhat`` and their bulk and tail ESS at least ``min_ess``; or until
        ``max_iterations`` sweeps or ``max_seconds`` of wall time. ``Chains.converged_`` and
        ``Chains.stop_reason_`` say which.
    block : sweeps per task (default 20, at most ``iterations``). Ctrl-C cancels the tasks and
        keeps every finished block.
    burn_in : sweeps dropped from each chain for the summaries (default: the first half).
    seed : chain c's sweeps are seeded from ``SeedSequence(seed, spawn_key=(c, block))``: the
        same seed gives the same chains, locally or on Dask, on any number of workers.
    init : where the chains start: ``"dispersed"`` starts the even chains from one pattern and
        the odd ones from many (``DPGP(init="one")``, ``init="many"``), as practitioners advise
        for DP mixtures: chains that agree from such different starts have forgotten them.
        ``"sequential"`` (default), ``"one"`` or ``"many"``: every chain so.
    settings : passed to :class:`dpgp.DPGP` (``assignment``, ``alpha``, ...); ``n_threads``
        defaults to 1 (one core per chain).
    """
    from ..model.estimator import DPGP, choose_inputs
    from ..model.sharded import ShardSource, check_client, manifest_of

    manifest = manifest_of(frames)
    if not (isinstance(n_chains, (int, np.integer)) and n_chains >= 1):
        raise InvalidInputError(f"n_chains must be a positive integer, got {n_chains!r}")
    if until not in (None, "converged"):
        raise InvalidInputError(f"until must be None or 'converged', got {until!r}")
    for name, value in (("iterations", iterations), ("max_iterations", max_iterations)):
        if not (isinstance(value, (int, np.integer)) and value >= 1):
            raise InvalidInputError(f"{name} must be a positive integer, got {value!r}")
    if not (isinstance(seed, (int, np.integer)) and seed >= 0):
        raise InvalidInputError(f"seed must be a non-negative integer, got {seed!r}")
    if burn_in is not None and not (isinstance(burn_in, (int, np.integer)) and burn_in >= 0):
        raise InvalidInputError(f"burn_in must be a non-negative integer or None, got {burn_in!r}")
    if not rhat > 1.0 or not min_ess > 0:
        raise InvalidInputError(f"need rhat > 1 and min_ess > 0, got rhat={rhat!r}, min_ess={min_ess!r}")
    reserved = sorted(set(settings) & set(_RESERVED))
    if reserved:
        raise InvalidInputError(f"{reserved} are fit_chains' own arguments, not settings to pass to DPGP")
    if settings.get("checkpoint") is not None:
        # Every block of every chain would write the same file; a chain whose worker dies
        # already reruns only its lost block.
        raise InvalidInputError(
            "checkpoint is a setting of a single fit (DPGP(checkpoint=...).fit), not of fit_chains; leave it out"
        )
    if settings.get("inputs") == "position+heading":
        # A chain's blocks hand their state on as a model file without the frames' headings or
        # the patterns' heading length scales: refuse rather than fail after the first block.
        raise InvalidInputError(
            "fit_chains does not run fields over heading yet (issue 34): fit one chain with "
            "DPGP(inputs='position+heading').fit"
        )
    if settings.get("inputs") == "auto" and choose_inputs(True)["inputs"] == "position+heading":
        # auto would pick fields over heading on frames with tracks (HEADING_EVIDENCE): the same refusal
        raise InvalidInputError(
            "fit_chains does not run fields over heading yet (issue 34), which inputs='auto' picks for frames "
            "with tracks: pass inputs='position' to fit_chains, or fit one chain with DPGP(inputs='auto').fit"
        )
    if init not in ("sequential", "one", "many", "dispersed"):
        raise InvalidInputError(f"init must be 'sequential', 'one', 'many' or 'dispersed', got {init!r}")
    if init != "dispersed":
        settings = {**settings, "init": init}
    settings = {"n_threads": 1, **settings}
    try:
        DPGP(**settings)._check_settings()
    except TypeError as e:
        raise InvalidInputError(f"unknown DPGP setting: {e}") from None
    source = None
    if manifest is not None and DPGP(**settings)._runs_on_shards(None):
        check_client(client, manifest)
        source = ShardSource(manifest, client, fingerprint=True)  # the chains' models name the shards by it
    else:
        frames = as_frames(frames)
    target = iterations if until is None else max_iterations
    block = min(20 if block is None else int(block), target)
    if block < 1:
        raise InvalidInputError(f"block must be a positive integer, got {block!r}")
    mark("chains start")
    with Interrupts() as interrupts:
        with interrupts.interruptible():  # scattering the frames waits for the cluster
            if source is not None:
                engine: Any = _ThreadEngine(source, n_chains)
                frames = source
            elif client is None:
                workers = n_workers if n_workers is not None else min(n_chains, os.cpu_count() or 1)
                engine = _LocalEngine(frames, max(1, int(workers)))
            else:
                engine = _DaskEngine(client, frames)
        runner = _Runner(engine, frames, settings, n_chains, seed, block, progress, interrupts, init)
        try:
            runner.resolve()
            runner.run(until, iterations, rhat, min_ess, max_iterations, max_seconds)
        finally:
            engine.close()
        return runner.chains(burn_in, rhat, min_ess)


class _Runner:
    """Submits blocks, collects them, checks the stopping rule between rounds."""

    def __init__(
        self,
        engine: Any,
        frames: Any,
        settings: dict[str, Any],
        n_chains: int,
        seed: int,
        block: int,
        progress: bool,
        interrupts: Interrupts,
        init: str = "sequential",
    ) -> None:
        self.engine, self.frames, self.settings, self.seed, self.block = engine, frames, settings, seed, block
        self.interrupts = interrupts
        self.names = [f"chain{c}" for c in range(n_chains)]
        self.blocks: list[list[_Block]] = [[] for _ in range(n_chains)]
        self.failures: dict[str, str] = {}
        self.attempts = [0] * n_chains
        self.converged = False
        self.reason = ""
        self.interrupted = False
        self.progress = progress
        self.checks: list[dict[str, Any]] = []
        self.pending: dict[Any, int] = {}  # future -> chain
        self.resolved: dict[str, Any] | None = None
        self.chain_settings = settings
        self.init = init

    def sweeps(self, c: int) -> int:
        return sum(len(b.labels) for b in self.blocks[c])

    def _submit(self, c: int, n: int) -> Any:
        b = len(self.blocks[c])
        state = self.blocks[c][-1].state if b else None
        settings = self.chain_settings
        if self.init == "dispersed" and state is None:  # chains start from one and from many patterns
            settings = {**settings, "init": ("one", "many")[c % 2]}
        args = (settings, block_seed(self.seed, c, b), state, n)
        return self.engine.submit(f"{self.names[c]}-block{b}", _run_block, *args)

    def _feed(self, c: int, target: int) -> None:
        """Submit chain c's next block unless it has reached ``target`` sweeps or failed."""
        left = target - self.sweeps(c)
        if left > 0 and self.names[c] not in self.failures:
            self.pending[self._submit(c, min(self.block, left))] = c

    def _wait(self, futures: list[Any]) -> set[Any]:
        """The finished ones of ``futures`` (at least one): the only place a Ctrl-C is raised."""
        while True:
            with self.interrupts.interruptible():
                done = self.engine.wait(futures, _POLL_SECONDS)
            if done:
                return done

    def _round(self, target: int, bar: Any) -> None:
        """Advance every live chain to ``target`` sweeps, each as soon as its last block is in."""
        for c in range(len(self.names)):
            self._feed(c, target)
        while self.pending:
            for f in self._wait(list(self.pending)):
                if f in self.pending:  # else: a block resubmitted after its worker pool died
                    self._take(f, target, bar)

    def _take(self, f: Any, target: int, bar: Any) -> None:
        """A finished task: keep its block and submit the chain's next, or handle its failure."""
        try:
            with self.interrupts.interruptible():  # fetching it from a cluster may wait
                result, error = f.result(), None
        except (KeyboardInterrupt, SystemExit):
            raise
        except BaseException as e:  # noqa: BLE001 - any failure belongs to this chain
            result, error = None, e
        c = self.pending.pop(f)
        if error is None:
            self._done(c, result, bar)
            self._feed(c, target)
        elif self.engine.broken(error):
            self._retry([c, *self.pending.values()], target, bar)
        else:
            self._fail(c, error)

    def _done(self, c: int, result: _Block, bar: Any) -> None:
        self.blocks[c].append(result)
        mark(f"block {self.names[c]}-block{len(self.blocks[c]) - 1} received")
        if bar is not None:
            bar.update(len(result.labels))

    def _stop(self, bar: Any) -> None:
        """After Ctrl-C: keep the blocks that finished meanwhile, cancel the others."""
        for f, c in self.pending.items():
            result = self.engine.finished(f)
            if result is not None:
                self._done(c, result, bar)
        self.engine.cancel(list(self.pending))
        self.pending.clear()
        self.interrupted = True
        self.interrupts.handled()

    def _fail(self, c: int, error: BaseException) -> None:
        text = f"{type(error).__name__}: {error}"
        self.failures[self.names[c]] = text
        warnings.warn(f"{self.names[c]} failed and is left out: {text}", stacklevel=5)

    def _retry(self, lost: list[int], target: int, bar: Any) -> None:
        """A local worker process died and took the pool with it: keep the blocks that had
        finished, run the others again once (they are deterministic), fail them the second time."""
        finished = {c: f for f, c in self.pending.items() if f.done() and not f.cancelled() and f.exception() is None}
        self.pending.clear()
        for c in lost:
            if c in finished:
                self._done(c, finished[c].result(), bar)
            elif self.attempts[c] < 1:
                self.attempts[c] += 1
            else:
                self._fail(c, RuntimeError("its worker process died twice"))
                continue
            self._feed(c, target)

    def resolve(self) -> None:
        """Resolve the "auto" settings once, as a task, and run every chain with the values."""
        from ..model.estimator import DPGP

        merged = {**DPGP().get_params(), **self.settings}
        if not merged.get("preset") and "auto" not in [v for v in merged.values() if isinstance(v, str)]:
            return  # every setting is a value already
        future = self.engine.submit("resolve-settings", _resolve, self.settings, self.seed)
        try:
            self._wait([future])
            with self.interrupts.interruptible():  # fetching it from a cluster may wait
                self.resolved, likelihood, sampler = future.result()
        except KeyboardInterrupt:
            self.engine.cancel([future])
            self.interrupts.handled()
            raise  # nothing to keep
        except BaseException as e:  # noqa: BLE001
            if isinstance(e, DpgpError):
                raise
            raise ChainsFailedError(f"resolving the settings failed: {type(e).__name__}: {e}") from e
        self.chain_settings = {
            **_explicit(self.settings, self.resolved),
            "likelihood": likelihood,
            "sampler": sampler,
        }

    def run(
        self,
        until: str | None,
        iterations: int,
        rhat: float,
        min_ess: float,
        max_iterations: int,
        max_seconds: float | None,
    ) -> None:
        start = time.perf_counter()
        target = iterations if until is None else self.block
        bar = _bar(len(self.names) * (iterations if until is None else max_iterations), self.progress)
        try:
            while True:
                self._round(target, bar)
                if not self._live():
                    raise ChainsFailedError(
                        "every chain failed: " + "; ".join(f"{k}: {v}" for k, v in self.failures.items())
                    )
                if until is None:
                    self.reason = f"ran the {iterations} sweeps asked for"
                    return
                ok, why = self._check(target, rhat, min_ess)
                if bar is not None:
                    bar.set_postfix_str(why[:60])
                if ok:
                    self.converged, self.reason = True, f"converged after {target} sweeps: {why}"
                    return
                if target >= max_iterations:
                    self.reason = f"not converged: max_iterations={max_iterations} reached ({why})"
                    return
                if max_seconds is not None and time.perf_counter() - start >= max_seconds:
                    self.reason = f"not converged: max_seconds={max_seconds:g} reached after {target} sweeps ({why})"
                    return
                target = min(target + self.block, max_iterations)
        except KeyboardInterrupt:
            self._stop(bar)
            # The sweeps the chains keep: chains cut to the shortest one that has a block.
            done = min((self.sweeps(c) for c in self._live() if self.blocks[c]), default=0)
            self.reason = f"interrupted (Ctrl-C) after {done} sweeps"
            warnings.warn(f"fit_chains {self.reason}; the chains keep every finished block", stacklevel=3)
        finally:
            if bar is not None:
                bar.close()

    def _live(self) -> list[int]:
        return [c for c in range(len(self.names)) if self.names[c] not in self.failures]

    def _check(self, n: int, rhat: float, min_ess: float) -> tuple[bool, str]:
        live = self._live()
        traces = {
            q: np.stack([np.concatenate([b.traces[q] for b in self.blocks[c]]) for c in live]) for q in QUANTITIES
        }
        verdict = convergence(traces, n // 2, rhat, min_ess)
        self.checks.append({"sweeps": n, **verdict})
        return verdict["ok"], verdict["why"]

    def chains(self, burn_in: int | None, rhat: float, min_ess: float) -> Chains:
        live = [c for c in range(len(self.names)) if self.names[c] not in self.failures and self.blocks[c]]
        if not live:
            if self.interrupted:
                raise KeyboardInterrupt("Ctrl-C before any block had finished: nothing to keep")
            raise ChainsFailedError(str(self.failures))
        return Chains(
            frames=self.frames,
            settings=self.settings,
            seed=self.seed,
            names=[self.names[c] for c in live],
            blocks=[self.blocks[c] for c in live],
            burn_in=burn_in,
            converged=self.converged,
            stop_reason=self.reason,
            failures=dict(self.failures),
            checks=self.checks,
            thresholds={"rhat": rhat, "min_ess": min_ess},
            resolved=self.resolved,
            retried={self.names[c]: n for c, n in enumerate(self.attempts) if n},
        )


def convergence(traces: dict[str, np.ndarray], burn_in: int, rhat: float, min_ess: float) -> dict[str, Any]:
    """The stopping rule on (chains, sweeps) traces after dropping ``burn_in`` sweeps: each
    quantity has R̂ ≤ ``rhat`` and bulk and tail ESS ≥ ``min_ess``. A quantity that never varies
    (every chain, every kept sweep: e.g. a fixed α) has no R̂ and passes."""
    out: dict[str, Any] = {"rhat": {}, "ess_bulk": {}, "ess_tail": {}}
    failing = []
    for q, x in traces.items():
        kept = x[:, burn_in:]
        r, eb, et = diagnostics.rhat(kept), diagnostics.ess_bulk(kept), diagnostics.ess_tail(kept)
        out["rhat"][q], out["ess_bulk"][q], out["ess_tail"][q] = r, eb, et
        constant = kept.size > 0 and np.ptp(kept) == 0 and kept.shape[1] >= 4
        if constant:
            continue
        if not r <= rhat:
            failing.append(f"R̂({q}) = {r:.3f} > {rhat:g}")
        if not min(eb, et) >= min_ess:
            failing.append(f"ESS({q}) = {min(eb, et):.0f} < {min_ess:g}")
    out["ok"] = not failing
    out["why"] = "; ".join(failing) if failing else f"R̂ ≤ {rhat:g} and ESS ≥ {min_ess:g} for {', '.join(traces)}"
    return out


def _bar(total: int, enabled: bool) -> Any:
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc="dpgp chains", unit="sweep")


# --- the result --------------------------------------------------------------------------------
class Chains:
    """Independent chains of a DP-GP fit (what :func:`fit_chains` returns).

    Attributes
    ----------
    names : the chains' names (``chain0``, ...), failed chains left out.
    traces : per quantity (``log_joint``, ``n_patterns``, ``alpha``, ``moves``, ``seconds``), an
        array shaped (chains, sweeps).
    labels : (chains, sweeps, N) int32, each sweep's partition (canonical labels).
    burn_in : sweeps dropped from each chain by every summary (settable).
    converged_, stop_reason_ : whether and why the run stopped; ``failures_`` maps a failed
        chain's name to its error; ``retried_`` names the chains whose block was run again
        after a local worker process died; ``checks_`` the stopping rule's verdict at each round.
    models : each chain's final state as a fitted :class:`dpgp.DPGP` (built on first use).
    """

    def __init__(
        self,
        frames: Any,  # Frames, or the chains' ShardSource
        settings: dict[str, Any],
        seed: int,
        names: list[str],
        blocks: list[list[_Block]],
        burn_in: int | None,
        converged: bool,
        stop_reason: str,
        failures: dict[str, str],
        checks: list[dict[str, Any]],
        thresholds: dict[str, float],
        resolved: dict[str, Any] | None = None,
        retried: dict[str, int] | None = None,
    ) -> None:
        self.frames, self.settings, self.seed, self.names = frames, settings, seed, names
        n = min(sum(len(b.labels) for b in bl) for bl in blocks)  # chains cut to a common length
        self.traces = {q: np.stack([np.concatenate([b.traces[q] for b in bl])[:n] for bl in blocks]) for q in _TRACES}
        self.traces["n_patterns"] = self.traces["n_patterns"].astype(np.int64)
        self.traces["moves"] = self.traces["moves"].astype(np.int64)
        self.labels = np.stack([np.concatenate([b.labels for b in bl])[:n] for bl in blocks])
        self._states = [bl[-1].state for bl in blocks]
        if burn_in is not None and not burn_in < n:  # e.g. a run interrupted early
            warnings.warn(f"burn_in={burn_in} leaves no sweep of {n}; using {n // 2}", stacklevel=3)
            burn_in = None
        self.burn_in = n // 2 if burn_in is None else burn_in
        self.converged_, self.stop_reason_, self.failures_ = converged, stop_reason, failures
        self.checks_, self.thresholds = checks, thresholds
        self.resolved = resolved  # what the "auto" settings resolved to (dpgp.defaults), or None
        self.retried_ = retried or {}  # chains whose block was rerun after a local worker died
        self._models: list[Any] | None = None
        self._estimates: dict[tuple[str, int, int], partition.PointEstimate] = {}
        self._chain_estimates: dict[tuple[str, int], list[np.ndarray]] = {}

    # --- shape --------------------------------------------------------------------------------
    @property
    def n_chains(self) -> int:
        return len(self.names)

    @property
    def n_sweeps(self) -> int:
        return self.labels.shape[1]

    @property
    def burn_in(self) -> int:
        return self._burn_in

    @burn_in.setter
    def burn_in(self, value: int) -> None:
        if not (isinstance(value, (int, np.integer)) and 0 <= value < self.labels.shape[1]):
            raise InvalidInputError(f"burn_in must be an integer in [0, {self.labels.shape[1]}), got {value!r}")
        self._burn_in = int(value)

    def __repr__(self) -> str:
        state = "converged" if self.converged_ else "not converged"
        failed = f", {len(self.failures_)} failed" if self.failures_ else ""
        return f"Chains({self.n_chains} chains × {self.n_sweeps} sweeps, burn-in {self.burn_in}, {state}{failed})"

    def draws(self, quantity: str) -> np.ndarray:
        """(chains, kept sweeps) draws of a traced quantity after the burn-in."""
        if quantity not in self.traces:
            raise InvalidInputError(f"no trace {quantity!r}; traces: {sorted(self.traces)}")
        return self.traces[quantity][:, self.burn_in :]

    def kept_labels(self) -> np.ndarray:
        """The kept sweeps' partitions of every chain, stacked: (chains × kept, N)."""
        return self.labels[:, self.burn_in :].reshape(-1, self.labels.shape[2])

    # --- diagnostics --------------------------------------------------------------------------
    def rhat(self) -> dict[str, float]:
        """Rank-normalised split-R̂ (Vehtari et al. 2021) of the log joint, K and α over the kept sweeps."""
        return {q: diagnostics.rhat(self.draws(q)) for q in QUANTITIES}

    def ess(self, method: str = "bulk") -> dict[str, float]:
        """Bulk (``method="bulk"``) or tail ESS of the log joint, K and α over the kept sweeps."""
        return {q: diagnostics.ess(self.draws(q), method) for q in QUANTITIES}

    def summary(self) -> Any:
        """A table (pandas DataFrame) per quantity: mean, sd, R̂, bulk ESS, tail ESS; and a row
        ``partition_ari``: the adjusted Rand index between every two chains' summary partitions
        (:meth:`agreement`), its mean, sd and minimum (label-free, it says whether the chains found
        the same patterns)."""
        import pandas as pd

        rows = {
            q: {
                "mean": float(self.draws(q).mean()),
                "sd": float(self.draws(q).std(ddof=1)) if self.draws(q).size > 1 else float("nan"),
                "rhat": diagnostics.rhat(self.draws(q)),
                "ess_bulk": diagnostics.ess_bulk(self.draws(q)),
                "ess_tail": diagnostics.ess_tail(self.draws(q)),
            }
            for q in QUANTITIES
        }
        pairs = self.agreement()[np.triu_indices(self.n_chains, 1)]
        nan = float("nan")
        rows["partition_ari"] = {
            "mean": float(pairs.mean()) if pairs.size else nan,
            "sd": float(pairs.std(ddof=1)) if pairs.size > 1 else nan,
            "min": float(pairs.min()) if pairs.size else nan,
        }
        return pd.DataFrame.from_dict(rows, orient="index")

    def chain_estimates(self, loss: str = "vi") -> list[np.ndarray]:
        """Each chain's summary partition: the point estimate (:func:`dpgp.partition.salso`) of its
        own kept sweeps. Cached."""
        key = (loss, self.burn_in)
        if key not in self._chain_estimates:
            kept = self.labels[:, self.burn_in :]
            self._chain_estimates[key] = [
                partition.salso(kept[c], loss, n_runs=4, init=self.labels[c, -1:], seed=self.seed).labels
                for c in range(self.n_chains)
            ]
        return self._chain_estimates[key]

    def agreement(self, loss: str = "vi") -> np.ndarray:
        """(chains, chains): the adjusted Rand index between every two chains' summary partitions
        (:meth:`chain_estimates`); 1 on the diagonal."""
        from ..evaluate.metrics import adjusted_rand_index

        est = self.chain_estimates(loss)
        n = len(est)
        out = np.ones((n, n))
        for a in range(n):
            for b in range(a + 1, n):
                out[a, b] = out[b, a] = adjusted_rand_index(est[a], est[b])
        return out

    def rhat_by_sweeps(self, points: int = 30) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """R̂ of each quantity had the run stopped after n sweeps (the second half kept), for up
        to ``points`` values of n: (n, {quantity: R̂})."""
        ns = np.unique(np.linspace(8, self.n_sweeps, max(points, 1)).astype(int))
        ns = ns[ns >= 8] if self.n_sweeps >= 8 else ns[:0]
        out = {q: np.array([diagnostics.rhat(self.traces[q][:, n // 2 : n]) for n in ns]) for q in QUANTITIES}
        return ns, out

    def to_inference_data(self) -> Any:
        """The traces as an ArviZ ``InferenceData``: the kept sweeps as ``posterior`` and the
        burn-in as ``warmup_posterior`` (variables ``log_joint``, ``n_patterns``, ``alpha``),
        moves and seconds per sweep as ``sample_stats``. Needs ArviZ (``pip install arviz``)."""
        try:
            import arviz as az
        except ImportError:
            raise ImportError("to_inference_data needs ArviZ: pip install arviz") from None
        b = self.burn_in
        post = {q: self.traces[q][:, b:] for q in QUANTITIES}
        stats = {q: self.traces[q][:, b:] for q in ("moves", "seconds")}
        warm = {q: self.traces[q][:, :b] for q in QUANTITIES} if b else None
        warm_stats = {q: self.traces[q][:, :b] for q in ("moves", "seconds")} if b else None
        return az.from_dict(
            posterior=post,
            sample_stats=stats,
            warmup_posterior=warm,
            warmup_sample_stats=warm_stats,
            save_warmup=bool(b),
        )

    # --- the partition ------------------------------------------------------------------------
    def similarity(self, rows: Any = None) -> np.ndarray:
        """Posterior similarity: the share of kept sweeps (all chains) in which frames i and j
        share a pattern; (N, N) float32, or only ``rows``. Computed a block of rows at a time."""
        return partition.similarity(self.kept_labels(), rows=rows)

    def point_estimate(self, loss: str = "vi", n_runs: int = 8) -> partition.PointEstimate:
        """The partition minimising the posterior expected ``loss`` (``"vi"`` or ``"binder"``)
        over the kept sweeps, by SALSO-style search (:func:`dpgp.partition.salso`, seeded by the
        chains' seed), started also from each chain's last partition. Cached."""
        key = (loss, self.burn_in, n_runs)
        if key not in self._estimates:
            self._estimates[key] = partition.salso(
                self.kept_labels(), loss, n_runs=n_runs, init=self.labels[:, -1], seed=self.seed
            )
        return self._estimates[key]

    def credible_ball(self, loss: str = "vi", level: float = 0.95) -> partition.CredibleBall:
        """Wade & Ghahramani's credible ball around :meth:`point_estimate`."""
        return partition.credible_ball(self.point_estimate(loss).labels, self.kept_labels(), loss, level)

    # --- models -------------------------------------------------------------------------------
    @property
    def models(self) -> list[Any]:
        if self._models is None:
            self._models = [self._model(s) for s in self._states]
        return self._models

    def _model(self, state: _State, **extra: Any) -> Any:
        from ..model.estimator import DPGP

        # Every setting (defaults included): a model file's fallback reads them when nothing was
        # left to "auto".
        settings = {
            **DPGP().get_params(),
            **self.settings,
            "seed": self.seed,
            "iterations": self.n_sweeps,
            "progress": False,
        }
        return _model_at(self.frames, settings, replace(state, resolved=self.resolved or state.resolved), extra)

    def summary_dict(self, loss: str = "vi") -> dict[str, Any]:
        """What a model file keeps of the chains: R̂, ESS, burn-in, the stopping verdict and the
        point estimate's expected loss (no label traces)."""
        est = self.point_estimate(loss)
        return {
            "n_chains": self.n_chains,
            "names": self.names,
            "seed": self.seed,
            "n_sweeps": self.n_sweeps,
            "burn_in": self.burn_in,
            "converged": bool(self.converged_),
            "stop_reason": self.stop_reason_,
            "thresholds": self.thresholds,
            "failures": self.failures_,
            "rhat": self.rhat(),
            "ess_bulk": self.ess("bulk"),
            "ess_tail": self.ess("tail"),
            "n_patterns_last": [int(k) for k in self.traces["n_patterns"][:, -1]],
            "point_estimate": {"loss": est.loss, "expected_loss": est.expected_loss, "n_patterns": est.n_clusters},
        }

    def best_model(self, loss: str = "vi", keep_traces: bool = False) -> Any:
        """A fitted :class:`dpgp.DPGP` at the point-estimate partition, usable like any model.

        Each of its patterns takes the length scales of the chains' final pattern that overlaps
        it most (Jaccard index over frames), α the median of the kept α draws. The chain summary
        is in ``chain_summary_`` (saved with the model); with ``keep_traces`` the kept sweeps'
        labels go to ``label_trace_`` (and so into the model file) too."""
        est = self.point_estimate(loss)
        ls = _matching_length_scales(est.labels, self._states)
        alpha = float(np.median(self.draws("alpha")))
        first = self._states[0]
        noise = None
        if all(s.pattern_noise_var is not None for s in self._states):  # per-pattern noise: the same match
            noise = _matching_length_scales(est.labels, self._states, "pattern_noise_var")
        state = _State(est.labels.astype(np.int64), ls, alpha, first.params, None, first.engine, noise)
        model = self._model(state, history={}, n_iter=self.n_sweeps, converged=bool(self.converged_))
        model.chain_summary_ = self.summary_dict(loss)
        if keep_traces:
            model.label_trace_ = self.kept_labels().astype(np.int64)
        return model


def _matching_length_scales(labels: np.ndarray, states: list[_State], attr: str = "length_scales") -> np.ndarray:
    """For each cluster of ``labels``, the length scales (or another per-pattern pair ``attr``,
    such as ``pattern_noise_var``) of the final-state pattern (any chain) with the largest Jaccard
    overlap."""
    k = int(labels.max()) + 1
    best = np.full(k, -1.0)
    out = np.zeros((k, 2))
    size = np.bincount(labels, minlength=k)
    for s in states:
        ks = int(s.labels.max()) + 1
        joint = np.bincount(labels * ks + s.labels, minlength=k * ks).reshape(k, ks)
        union = size[:, None] + np.bincount(s.labels, minlength=ks)[None, :] - joint
        jac = joint / union
        j = jac.argmax(axis=1)
        better = jac[np.arange(k), j] > best
        best[better] = jac[np.arange(k), j][better]
        out[better] = np.asarray(getattr(s, attr))[j[better]]
    return out


__all__ = ["fit_chains", "Chains", "ChainsFailedError", "convergence", "block_seed", "QUANTITIES"]
