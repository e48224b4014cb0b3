"""One sub-cluster chain over frames stored as shards (issue 33): in this process, or with each
shard served by a Dask worker.

The chain's leader (this process) holds the patterns' sums and parameters and runs every global
step; the frames stay in their shards, and so do their labels (the shards draw, move and regroup
them on request, and answer with sums, counts and the few frames a move needs). Each sweep it sends requests to the shards
(draw every frame's label given the drawn fields, sum these frames, score those), and a shard
answers from its frames alone (the protocol: ``rust/core/src/subcluster_shard.rs``). A shard's
answer depends only on its frames and the request, and answers are added up in shard order, so
the same seed and the same shards give the same chain in this process and on any cluster, and a
shard whose worker is lost is read again by a new actor on a live worker (:class:`DaskShards`).

The settings that the estimator resolves from data (``"auto"`` defaults, the basis, mean and
variance of the velocities) come from :func:`settings_sample`: every frame up to
:data:`SAMPLE_FRAMES`, else that many evenly spaced, with the positions' full extent, read one
shard at a time by the leader, so that both ways of serving the shards start from one setting.
"""

from __future__ import annotations

import gc
import hashlib
import os
import threading
import time
import uuid
from typing import Any

import numpy as np

from .. import _core
from ..data._shardfile import ShardManifest, read_manifest
from ..data.frames import Frames
from ..data.shards import read_shard
from ..exceptions import InvalidInputError

#: Frames from which a sharded fit resolves its data-dependent settings.
SAMPLE_FRAMES = 20_000
#: Times in a row a request is sent to a new actor of its shard after its worker was lost.
REPLACEMENTS = 3
#: Seconds :meth:`DaskShards.close` waits for the workers to drop a chain's shards.
DROP_SECONDS = 10.0


class LabelsLost(RuntimeError):
    """A shard does not hold the chain's labels: the worker serving it replaced a lost one (or a
    request ran beside another copy of the shard). The fit sets the labels again from its copy of
    the last rebuild and redoes the sweeps since, which gives the same chain."""


def settings_sample(
    manifest: ShardManifest, client: Any = None, fingerprint: bool = False
) -> tuple[Frames, np.ndarray, str | None]:
    """The frames a sharded fit resolves its settings from (all up to :data:`SAMPLE_FRAMES`,
    else as many evenly spaced), the corners ``[[x_min, y_min], [x_max, y_max]]`` of every
    position and, with ``fingerprint``, the frames' :func:`combined_fingerprint`. Each shard is
    read alone (by ``client``'s workers when given, so that the leader never holds one) and gives
    its part (:func:`shard_digest`)."""
    n = manifest.n_frames
    args = (os.path.abspath(manifest.directory), n)
    digests = _per_shard(manifest, client, shard_digest, *args, fingerprint)
    lo = np.min([d[0] for d in digests], axis=0)
    hi = np.max([d[1] for d in digests], axis=0)
    frame, xy, v = (np.concatenate([d[k] for d in digests]) for k in (2, 3, 4))
    sample = Frames.from_arrays(frame, xy[:, 0], xy[:, 1], v[:, 0], v[:, 1])
    sha = combined_fingerprint(manifest, [d[5] for d in digests]) if fingerprint else None
    return sample, np.array([lo, hi]), sha


def shards_fingerprint(manifest: ShardManifest, client: Any = None) -> str:
    """The :func:`combined_fingerprint` of the frames in ``manifest``'s shards, each shard read
    and hashed alone (by ``client``'s workers when given)."""
    return combined_fingerprint(manifest, _per_shard(manifest, client, shard_sha256, manifest.directory))


def combined_fingerprint(manifest: ShardManifest, shard_hashes: list[Any]) -> str:
    """SHA-256 over each shard's frame range and :func:`shard_sha256`, in shard order: what a
    checkpoint of a sharded fit records, so that a resumed chain runs on exactly its shards."""
    h = hashlib.sha256()
    for info, digest in zip(manifest.shards, shard_hashes):
        h.update(f"{info.start}:{info.stop}:{digest};".encode())
    return h.hexdigest()


def shard_sha256(directory: str, i: int) -> str:
    """A worker's task: the fingerprint (:func:`dpgp.io.checkpoint.fingerprint`) of shard ``i``'s
    frames."""
    from ..io.checkpoint import fingerprint

    part, _ = read_shard(directory, i)
    out = fingerprint(part)
    del part
    _release_arrow_memory()
    return out


def _per_shard(manifest: ShardManifest, client: Any, task: Any, *args: Any) -> list[Any]:
    """``task(*args, i)`` for every shard ``i``, in this process or on ``client``'s workers (the
    results in shard order)."""
    if client is None:
        return [task(*args, i) for i in range(manifest.n_shards)]
    return list(client.gather([client.submit(task, *args, i, pure=False) for i in range(manifest.n_shards)]))


def shard_digest(
    directory: str, n_frames: int, fingerprint: bool, i: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, str | None]:
    """Shard ``i``'s part of :func:`settings_sample`: its positions' least and greatest
    coordinates, the rows (frame number, position, velocity) of its frames among the evenly
    spaced sample of all ``n_frames`` and, with ``fingerprint``, its :func:`shard_sha256`."""
    from ..io.checkpoint import fingerprint as sha256_of

    part, start = read_shard(directory, i)
    take = np.arange(n_frames) if n_frames <= SAMPLE_FRAMES else (np.arange(SAMPLE_FRAMES) * n_frames) // SAMPLE_FRAMES
    mine = take[(take >= start) & (take < start + len(part))] - start
    sub = part[mine]
    out = (
        part.xy.min(axis=0), part.xy.max(axis=0), np.repeat(mine + start, sub.sizes), np.array(sub.xy), np.array(sub.v),
        sha256_of(part) if fingerprint else None,
    )  # fmt: skip
    del part, sub
    _release_arrow_memory()
    return out


def _release_arrow_memory() -> None:
    """Give back what Arrow's pool kept from reading a shard (it keeps freed memory otherwise)."""
    import pyarrow as pa

    pa.default_memory_pool().release_unused()


def core_shard(directory: str | ShardManifest, i: int, headed: bool = False) -> Any:
    """Shard ``i`` read as the core's ``Shard`` (what answers the chain's requests); ``headed``:
    with its points' previous headings, for fields over heading."""
    part, start = read_shard(directory, i)
    h = None
    if headed:
        if part.prev_heading is None:
            raise InvalidInputError(
                f"shard {i} has no previous headings (prev_heading): write the shards from frames made by "
                "make_frames from tracks, or fit with inputs='position'"
            )
        h = np.ascontiguousarray(part.prev_heading, dtype=np.float64)
    shard = _core.Shard(part.xy, part.v, part.offsets, start, h)
    del part
    _release_arrow_memory()
    return shard


def local_shards(manifest: ShardManifest, headed: bool = False) -> list[Any]:
    """Every shard read into this process as the core's ``Shard``, in order."""
    return [core_shard(manifest, i, headed) for i in range(manifest.n_shards)]


# --- served by Dask workers ------------------------------------------------------------------
class ShardServer:
    """A Dask actor: shard ``i`` of ``directory`` read once into the worker that holds the actor,
    answering the chain's requests there. Requests to an actor go from the leader straight to its
    worker (no scheduler in between): a sweep's many short round trips take a third of a task's."""

    def __init__(self, directory: str, i: int, headed: bool = False):
        self.directory = directory
        self._shard = core_shard(directory, i, headed)

    def handle(self, request: bytes) -> bytes:
        return self._shard.handle(request)


class ShardSource:
    """Where chains over a directory of shards find their frames: read into this process once,
    or served by the workers of a Dask ``client`` through one :class:`DaskShards` link. A fit
    makes its own; :func:`dpgp.fit_chains` shares one among its chains, so that the shards are
    read once and every chain's requests go to the same workers. The settings sample
    (:func:`settings_sample`) is read once too, with the shards' fingerprint when
    ``fingerprint``."""

    def __init__(self, manifest: ShardManifest, client: Any = None, fingerprint: bool = False):
        self.manifest, self.client, self._fingerprint = manifest, client, fingerprint
        self.directory = os.path.abspath(manifest.directory)
        self._sample: tuple[Frames, np.ndarray, str | None] | None = None
        self._local: dict[bool, list[Any]] = {}  # by whether the shards carry headings
        self.link: DaskShards | None = None
        self._lock = threading.Lock()  # chains in threads ask for samplers at once
        self.stopping = threading.Event()  # set: the chains over it stop before their next sweep

    @property
    def sizes(self) -> list[int]:
        return [s.n_frames for s in self.manifest.shards]

    def sample(self, fingerprint: bool = False) -> tuple[Frames, np.ndarray, str | None]:
        """:func:`settings_sample` of the shards (read once; again only for a fingerprint the
        first read did not take)."""
        with self._lock:
            if self._sample is None or (fingerprint and self._sample[2] is None):
                self._sample = settings_sample(self.manifest, self.client, fingerprint or self._fingerprint)
            return self._sample

    def sampler(self, settings: Any) -> Any:
        """A sub-cluster chain with ``settings`` over these shards (with their previous headings
        when the settings are of fields over heading)."""
        headed = settings.get("heading_prior") is not None
        with self._lock:
            if self.client is None:
                if headed not in self._local:
                    self._local[headed] = local_shards(self.manifest, headed)
                return _core.Sampler.over_shards(self._local[headed], settings)
            if self.link is None or self.link.closed or self.link.headed != headed:
                if self.link is not None:
                    self.link.close()
                self.link = DaskShards(self.client, self.manifest, headed)
            return _core.Sampler.over_link(self.sizes, self.link, settings)

    def close(self) -> None:
        """Let the workers drop the shards (a later sampler loads them again)."""
        if self.link is not None:
            self.link.close()


class DaskShards:
    """The shards of ``manifest`` served by the workers of a Dask ``client``: each shard is read by
    one :class:`ShardServer` actor, spread over the workers, and kept there for the life of the
    chain (the actors' futures are held); each request goes to its shard's actor. Counts the
    requests, the bytes sent and received, and the seconds spent waiting for replies (chains in
    several threads may share it).

    A worker lost mid-fit takes its actors with it (Dask does not rebuild an actor): the shard is
    read again by a new actor on a live worker and the request sent there. The new shard holds no
    labels, so a request that needs them fails with :class:`LabelsLost` and the fit redoes its
    sweeps from its copy of the last rebuild (the same chain); it never computes with another
    copy's labels."""

    def __init__(self, client: Any, manifest: ShardManifest, headed: bool = False):
        self._client, self.headed = client, headed
        self._directory = os.path.abspath(manifest.directory)
        self._tag = uuid.uuid4().hex[:8]
        self._replaced = [0] * manifest.n_shards  # actors made again per shard (workers lost)
        workers = sorted(client.scheduler_info()["workers"])
        self._loads = [
            self._load(i, [workers[i % len(workers)]] if workers else None) for i in range(manifest.n_shards)
        ]
        self._actors = client.gather(self._loads)  # every shard read once, before the chain starts
        self._count = threading.Lock()
        self.bytes_sent = 0
        self.bytes_received = 0
        self.requests = 0
        self.calls = 0
        self.seconds = 0.0  # waiting for the workers (the rest of a sweep is the leader's)

    def _load(self, i: int, workers: list[str] | None) -> Any:
        key = f"dpgp-shard-{self._tag}-{i}-{self._replaced[i]}"
        pin: dict[str, Any] = {"workers": workers, "allow_other_workers": True} if workers else {}
        return self._client.submit(ShardServer, self._directory, i, self.headed, actor=True, key=key, **pin)

    @property
    def closed(self) -> bool:
        return not self._loads

    def __call__(self, jobs: list[tuple[int, bytes]]) -> list[bytes]:
        if self.closed:
            raise RuntimeError("the shards' link is closed: the workers have dropped the shards")
        t = time.perf_counter()
        pending = [self._send(s, request) for s, request in jobs]  # all sent, then all awaited
        replies = [self._reply(s, request, f) for (s, request), f in zip(jobs, pending)]
        with self._count:
            self.bytes_sent += sum(len(r) for _, r in jobs)
            self.bytes_received += sum(len(r) for r in replies)
            self.requests += len(jobs)
            self.calls += 1
            self.seconds += time.perf_counter() - t
        return replies

    def _send(self, s: int, request: bytes) -> Any:
        """``request`` sent to shard ``s``'s actor: the pending reply, or ``None`` when it could not
        be sent (its worker gone: :meth:`_reply` finds out and sends it again)."""
        try:
            return self._actors[s].handle(request)
        except (OSError, RuntimeError):
            return None

    def _reply(self, s: int, request: bytes, pending: Any) -> bytes:
        """Shard ``s``'s reply to ``request``, sent again to a new actor when its worker was lost
        (before or while it worked; up to :data:`REPLACEMENTS` times in a row)."""
        for attempt in range(REPLACEMENTS + 1):
            try:
                if pending is None:
                    pending = self._actors[s].handle(request)
                return pending.result()
            except LabelsLost:
                raise
            except (OSError, RuntimeError):  # the actor's worker is gone (a lost comm, a lost actor)
                if attempt == REPLACEMENTS or not self._lost(s):
                    raise
                self._replace(s)
                pending = None
        raise AssertionError("unreachable")  # pragma: no cover

    def _lost(self, s: int) -> bool:
        """Whether shard ``s``'s actor is gone: its future failed or no worker holds it."""
        f = self._loads[s]
        return f.status == "error" or not self._client.who_has([f]).get(f.key)

    def _replace(self, s: int) -> None:
        with self._count:
            self._replaced[s] += 1
        old = self._loads[s]
        self._loads[s] = self._load(s, None)
        self._actors[s] = self._loads[s].result()
        old.release()

    def close(self) -> None:
        """Let the workers drop the shards (the actors go with their futures; a fitted model then
        can no longer gather its frames from them; the estimator closes its link when it fits
        again). Waits up to :data:`DROP_SECONDS` for the workers to let the actors go."""
        if not self._loads:
            return
        keys = {f.key for f in self._loads}
        for f in self._loads:
            f.release()
        self._loads, self._actors = [], []
        gc.collect()  # a used actor proxy sits in a reference cycle, and holds its key until freed
        deadline = time.monotonic() + DROP_SECONDS
        try:
            while time.monotonic() < deadline and any(self._client.run(_holds, keys).values()):
                time.sleep(0.05)
        except Exception:  # noqa: BLE001 - a closed client or a gone cluster has nothing to drop
            pass


def _holds(keys: set[str], dask_worker: Any) -> bool:
    """Run on every worker by :meth:`DaskShards.close`: whether it still holds one of these actors."""
    return any(k in dask_worker.state.actors for k in keys)


def manifest_of(frames: Any) -> ShardManifest | None:
    """The manifest when ``frames`` is a directory of shards (or a :class:`ShardSource`), else ``None``."""
    if isinstance(frames, ShardSource):
        return frames.manifest
    if isinstance(frames, (str, os.PathLike)) and os.path.isdir(frames):
        return read_manifest(frames)
    return None


def check_client(client: Any, manifest: ShardManifest | None) -> None:
    """Refuse a client without a directory of shards to serve, before any work."""
    if client is None:
        return
    if manifest is None:
        raise InvalidInputError(
            "fit(..., client=) fits frames stored as shards: write them first with "
            "frames.to_parquet(directory, shards=n) and pass the directory"
        )
    if not hasattr(client, "submit") or not hasattr(client, "gather"):
        raise InvalidInputError(f"client must be a dask.distributed Client, got {type(client).__name__}")
