"""One chain over frames stored as shards (``DPGP.fit(directory, client=...)``): in this process
and on a real ``distributed.LocalCluster`` with 2 worker processes the same seed and shards give
the same chain, also when a worker process is killed mid-fit; the settings that cannot run over
shards are refused with a client; ``dpgp fit DIR --scheduler ADDRESS`` runs the fit on a cluster."""

from __future__ import annotations

import os
import signal
import threading
import time
from typing import Any

import numpy as np
import pytest

import dpgp
from dpgp import InvalidInputError
from dpgp.evaluate.metrics import canonical_labels
from sharded_common import SEED, assert_same_chain, cluster  # noqa: F401  (a fixture)

N_FRAMES, N_SHARDS, ITERATIONS = 600, 3, 3


@pytest.fixture(scope="module")
def shard_dir(tmp_path_factory):
    directory = tmp_path_factory.mktemp("sharded") / "frames"
    dpgp.datasets.synthetic("highway", N_FRAMES, seed=3).to_parquet(directory, shards=N_SHARDS)
    return directory


_IN_PROCESS: dict[int, dpgp.DPGP] = {}


def in_process(directory, iterations: int) -> dpgp.DPGP:
    """The in-process sharded fit of ``directory`` (one per sweep count for the module)."""
    if iterations not in _IN_PROCESS:
        _IN_PROCESS[iterations] = dpgp.DPGP(iterations=iterations, seed=SEED, progress=False).fit(directory)
    return _IN_PROCESS[iterations]


class _NoWorkClient:
    """A stand-in client that fails the test if the fit sends it any work."""

    def submit(self, *args: Any, **kwargs: Any) -> Any:
        raise AssertionError("the fit submitted work before refusing its settings")

    def gather(self, *args: Any, **kwargs: Any) -> Any:
        raise AssertionError("the fit gathered work before refusing its settings")


# --- in this process ---------------------------------------------------------------------------
def test_in_process_sharded_fit_is_reproducible(shard_dir):
    a = in_process(shard_dir, ITERATIONS)
    b = dpgp.DPGP(iterations=ITERATIONS, seed=SEED, progress=False).fit(shard_dir)
    assert_same_chain(a, b)
    assert a._shard_link is None
    assert len(a.labels_) == N_FRAMES and a.labels_.min() >= 0
    assert a.n_patterns_ >= 1 and a.labels_.max() < a.n_patterns_
    assert len(a.history_["log_joint"]) == ITERATIONS and a.n_iter_ == ITERATIONS
    assert a.likelihood_ == "hsgp"


def test_frames_of_a_sharded_fit_are_read_lazily_from_the_directory(shard_dir):
    model = dpgp.DPGP(iterations=1, seed=SEED, progress=False).fit(shard_dir)
    assert model.__dict__["_frames"] is None  # the fit never held them all
    expected = dpgp.read_frames(shard_dir)
    np.testing.assert_array_equal(model.frames_.xy, expected.xy)
    np.testing.assert_array_equal(model.frames_.v, expected.v)
    assert len(model.frames_) == N_FRAMES


def test_a_sampler_that_cannot_run_over_shards_reads_the_directory(tmp_path):
    directory = tmp_path / "small"
    frames = dpgp.datasets.synthetic("highway", 150, seed=3)
    frames.to_parquet(directory, shards=2)
    model = dpgp.DPGP(iterations=1, seed=SEED, progress=False, sampler="collapsed").fit(directory)
    assert len(model.labels_) == len(frames) and model.n_patterns_ >= 1
    assert model.__dict__["_frames"] is not None  # read into memory
    np.testing.assert_array_equal(model.frames_.xy, frames.xy)


# --- refusals ----------------------------------------------------------------------------------
def test_client_with_frames_not_in_shards_is_refused():
    frames = dpgp.datasets.synthetic("highway", 50, seed=1)
    with pytest.raises(InvalidInputError, match="to_parquet"):
        dpgp.DPGP(iterations=1, progress=False).fit(frames, client=_NoWorkClient())


@pytest.mark.parametrize(
    "setting",
    [{"likelihood": "exact"}, {"sampler": "collapsed"}, {"pattern_moments": True}],
    ids=str,
)
def test_client_with_settings_that_need_every_frame_is_refused_before_any_work(shard_dir, setting):
    model = dpgp.DPGP(iterations=1, progress=False, **setting)
    with pytest.raises(InvalidInputError, match="client="):
        model.fit(shard_dir, client=_NoWorkClient())
    assert not hasattr(model, "labels_")


def test_fields_over_heading_on_shards_without_headings_are_refused_before_any_work(shard_dir):
    model = dpgp.DPGP(iterations=1, progress=False, inputs="position+heading")
    with pytest.raises(InvalidInputError, match="carry none"):
        model.fit(shard_dir, client=_NoWorkClient())
    assert not hasattr(model, "labels_")


CKPT = dict(iterations=5, checkpoint_every=2, seed=SEED, progress=False, store_labels=True)


class _Recording(dpgp.DPGP):
    """A fit that keeps a copy of every checkpoint it writes."""

    def _write_checkpoint(self, traces):  # noqa: ANN001
        super()._write_checkpoint(traces)
        copies = self.__dict__.setdefault("copies", [])
        copy = f"{self.checkpoint}.{len(copies)}"
        with open(self.checkpoint, "rb") as src, open(copy, "wb") as dst:
            dst.write(src.read())
        copies.append(copy)


def same_fit(a: dpgp.DPGP, b: dpgp.DPGP) -> None:
    assert_same_chain(a, b)
    np.testing.assert_array_equal(a.label_trace_, b.label_trace_)
    strip = lambda h: {k: v for k, v in h.items() if k != "seconds"}  # noqa: E731
    assert strip(a.history_) == strip(b.history_) and a.n_iter_ == b.n_iter_


@pytest.fixture(scope="module")
def checkpointed(shard_dir, tmp_path_factory):
    """A 5-sweep fit over the shards checkpointing every 2 sweeps, and the same fit without."""
    path = tmp_path_factory.mktemp("ckpt") / "fit.ckpt"
    return _Recording(**CKPT, checkpoint=str(path)).fit(shard_dir), dpgp.DPGP(**CKPT).fit(shard_dir)


def test_a_sharded_checkpoint_holds_the_state_and_names_the_shards(shard_dir, checkpointed):
    fit, plain = checkpointed
    same_fit(fit, plain)  # writing checkpoints changes nothing
    with np.load(fit.copies[-1]) as archive:
        members = set(archive.files)
    assert not {m for m in members if m.startswith("frame_")}  # the frames stay in their shards
    assert {"labels", "resume_labels", "length_scales"} <= members
    meta = dpgp.io.read_metadata(fit.copies[-1])
    assert meta["format_version"] == 3
    assert meta["shards"]["directory"] == os.path.abspath(shard_dir)
    assert sum(meta["shards"]["sizes"]) == N_FRAMES and len(meta["shards"]["sizes"]) == N_SHARDS


def fresh(copy: str, tmp_path) -> str:
    """A copy of a recorded checkpoint to resume (resuming writes on to the file it resumes)."""
    path = tmp_path / os.path.basename(copy)
    with open(copy, "rb") as src, open(path, "wb") as dst:
        dst.write(src.read())
    return str(path)


def test_resuming_from_every_sharded_checkpoint_gives_the_uninterrupted_fit(checkpointed, tmp_path):
    fit, _ = checkpointed
    assert [dpgp.io.read_metadata(c)["resume"]["sweeps_done"] for c in fit.copies] == [0, 2, 4, 4]
    for copy in fit.copies:
        resumed = dpgp.DPGP.resume(fresh(copy, tmp_path))
        same_fit(resumed, fit)
        assert resumed._frames is None  # continued over the shards, not from frames in the file


def test_load_reads_a_sharded_checkpoint_over_its_shards(checkpointed):
    fit, _ = checkpointed
    model = dpgp.DPGP.load(fit.copies[-1])
    np.testing.assert_array_equal(model.labels_, fit.labels_)
    np.testing.assert_array_equal(model.predict(fit.frames_[:50]), fit.predict(fit.frames_[:50]))


def test_a_sharded_checkpoint_refuses_shards_that_changed(shard_dir, checkpointed, tmp_path):
    fit, _ = checkpointed
    other = tmp_path / "other"
    frames = dpgp.read_frames(shard_dir)
    moved = frames.v.copy()
    moved[0, 0] += 0.5  # one velocity of one vehicle
    dpgp.Frames(frames.ids, frames.offsets, frames.xy, moved).to_parquet(other, shards=N_SHARDS)
    ckpt = tmp_path / "edited.ckpt"
    _repoint(fit.copies[1], ckpt, other)
    with pytest.raises(dpgp.ModelFileError, match="not the frames"):
        dpgp.DPGP.resume(ckpt)
    _repoint(fit.copies[1], ckpt, tmp_path / "gone")
    with pytest.raises(dpgp.ModelFileError, match="cannot be read"):
        dpgp.DPGP.resume(ckpt)


def _repoint(src, dst, directory) -> None:
    """Copy the checkpoint ``src`` to ``dst`` naming another directory of shards."""
    import json

    with np.load(src) as archive:
        arrays = {k: archive[k] for k in archive.files}
    meta = json.loads(str(arrays["metadata"]))
    meta["shards"]["directory"] = str(directory)
    arrays["metadata"] = np.array(json.dumps(meta))
    with open(dst, "wb") as fh:
        np.savez(fh, **arrays)


def test_client_resumes_only_a_checkpoint_over_shards(tmp_path):
    path = tmp_path / "plain.ckpt"
    dpgp.DPGP(iterations=1, progress=False, checkpoint=path).fit(dpgp.datasets.synthetic("highway", 30, seed=1))
    with pytest.raises(InvalidInputError, match="client="):
        dpgp.DPGP.resume(path, client=_NoWorkClient())


def test_cli_scheduler_refuses_frames_not_in_shards(tmp_path, capsys):
    from dpgp.cli import main

    data = tmp_path / "frames.csv"
    dpgp.datasets.synthetic("highway", 20, seed=1).to_pandas().to_csv(data, index=False)
    # No scheduler listens there: the input is refused before connecting.
    assert main(["fit", str(data), "-o", str(tmp_path / "m.npz"), "--scheduler", "tcp://127.0.0.1:9"]) == 1
    assert "directory of frame shards" in capsys.readouterr().err


def test_cli_scheduler_without_dask_says_what_to_install(shard_dir, tmp_path, capsys, monkeypatch):
    import sys

    from dpgp.cli import main

    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed raises ImportError
    assert main(["fit", str(shard_dir), "-o", str(tmp_path / "m.npz"), "--scheduler", "tcp://127.0.0.1:9"]) == 1
    assert "pip install 'dpgp[distributed]'" in capsys.readouterr().err


# --- many chains over shards (fit_chains) ---------------------------------------------------------
# two blocks of one sweep: the dispersed start's many patterns make the first sweep the longest
CHAINS = dict(iterations=2, block=1, seed=SEED, progress=False, init="dispersed")
_CHAINS: dict[str, Any] = {}


def chains_in_process(directory) -> Any:
    if "in process" not in _CHAINS:
        _CHAINS["in process"] = dpgp.fit_chains(directory, 2, **CHAINS)
    return _CHAINS["in process"]


def test_chains_over_shards_are_reproducible_and_summarised(shard_dir):
    chains = chains_in_process(shard_dir)
    again = dpgp.fit_chains(shard_dir, 2, **CHAINS)
    np.testing.assert_array_equal(chains.labels, again.labels)
    assert chains.traces["log_joint"].tolist() == again.traces["log_joint"].tolist()
    assert chains.labels.shape == (2, 2, N_FRAMES)
    # dispersed: chain 0 starts from one pattern, chain 1 from many (their first sweeps differ)
    assert chains.traces["n_patterns"][0, 0] != chains.traces["n_patterns"][1, 0]
    assert "partition_ari" in chains.summary().index
    model = chains.best_model()
    assert model._frames is None and model._frames_dir is not None  # a model over the shards
    np.testing.assert_array_equal(model.labels_, chains.point_estimate().labels)
    assert model.predict(model.frames_[:5]).shape == (5,)


def test_a_chains_model_over_shards_is_the_last_state_of_its_chain(shard_dir):
    chains = chains_in_process(shard_dir)
    for c, model in enumerate(chains.models):
        np.testing.assert_array_equal(canonical_labels(model.labels_), chains.labels[c, -1])


# --- on a LocalCluster -------------------------------------------------------------------------
def test_cluster_fit_is_the_in_process_chain(shard_dir, cluster):
    _, client = cluster
    on_cluster = dpgp.DPGP(iterations=ITERATIONS, seed=SEED, progress=False).fit(shard_dir, client=client)
    assert_same_chain(on_cluster, in_process(shard_dir, ITERATIONS))
    link = on_cluster._shard_link
    assert link is not None and link.requests > 0
    assert link.bytes_sent > 0 and link.bytes_received > 0


def test_cli_fits_shards_on_a_scheduler_address(shard_dir, cluster, tmp_path, capsys):
    from dpgp.cli import main

    out = tmp_path / "m.npz"
    args = ["fit", str(shard_dir), "-o", str(out), "--iterations", "1", "--seed", str(SEED), "--no-progress"]
    code = main([*args, "--scheduler", cluster[0].scheduler_address])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert f"{N_FRAMES} frames in {N_SHARDS} shards" in printed.out and f"wrote {out}" in printed.out
    np.testing.assert_array_equal(dpgp.DPGP.load(out).labels_, in_process(shard_dir, 1).labels_)


def test_a_sharded_checkpoint_resumes_on_a_cluster(checkpointed, cluster, tmp_path, capsys):
    from dpgp.cli import main

    fit, _ = checkpointed
    same_fit(dpgp.DPGP.resume(fresh(fit.copies[1], tmp_path), client=cluster[1]), fit)
    out = tmp_path / "m.npz"
    code = main(
        [
            "resume",
            fresh(fit.copies[0], tmp_path),
            "-o",
            str(out),
            "--no-progress",
            "--scheduler",
            cluster[0].scheduler_address,
        ]
    )
    assert code == 0, capsys.readouterr().err
    np.testing.assert_array_equal(dpgp.DPGP.load(out).labels_, fit.labels_)


def test_chains_over_shards_on_a_cluster_are_the_in_process_chains(shard_dir, cluster, tmp_path, capsys):
    from dpgp.cli import main

    # from one pattern, two sweeps: on a cluster each of the chains' passes over the shards is a
    # round trip (a sweep of 600 frames takes about 1.5 s against 0.25 s in process), and neither
    # the dispersed start (tested in process above) nor more sweeps is what the cluster changes
    settings = {**CHAINS, "init": "one"}
    on_cluster = dpgp.fit_chains(shard_dir, 2, cluster[1], **settings)
    here = dpgp.fit_chains(shard_dir, 2, **settings)
    np.testing.assert_array_equal(on_cluster.labels, here.labels)
    assert on_cluster.traces["log_joint"].tolist() == here.traces["log_joint"].tolist()
    out = tmp_path / "m.npz"
    args = ["fit", str(shard_dir), "-o", str(out), "--chains", "2", "--iterations", "2", "--no-progress"]
    code = main([*args, "--scheduler", cluster[0].scheduler_address])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert f"{N_FRAMES} frames in {N_SHARDS} shards" in printed.out and f"wrote {out}" in printed.out
    assert len(dpgp.DPGP.load(out).labels_) == N_FRAMES


def test_a_worker_killed_mid_fit_is_replaced_and_the_chain_is_unchanged(shard_dir, cluster):
    _, client = cluster
    iterations = 4
    model = dpgp.DPGP(iterations=iterations, seed=SEED, progress=False)
    killed: dict[str, Any] = {}
    done = threading.Event()

    def kill_after_the_first_sweep() -> None:
        # history_ is made afresh by fit; wait until this fit's first sweep is recorded.
        while not done.is_set():
            history = model.__dict__.get("history_")
            if history is not None and len(history["log_joint"]) >= 1:
                break
            time.sleep(0.02)
        else:
            return
        link = model._shard_link
        holder = next(iter(client.who_has([link._loads[0]])[link._loads[0].key]))
        pid = client.run(os.getpid)[holder]
        before = len(model.history_["log_joint"])
        os.kill(pid, signal.SIGKILL)
        killed.update(pid=pid, worker=holder, sweeps=(before, len(model.history_["log_joint"])))

    killer = threading.Thread(target=kill_after_the_first_sweep, daemon=True)
    killer.start()
    try:
        model.fit(shard_dir, client=client)
    finally:
        done.set()
        killer.join(timeout=30)
    assert "pid" in killed, "the worker was not killed during the fit"
    assert 1 <= killed["sweeps"][0] and killed["sweeps"][1] < iterations, killed  # mid-fit
    client.wait_for_workers(2, timeout=60)
    assert killed["pid"] not in client.run(os.getpid).values()  # the nanny started a new process
    assert_same_chain(model, in_process(shard_dir, iterations))


def _loaded(client: Any, directory: Any) -> int:
    """Shards of ``directory`` the cluster's worker processes hold."""
    from dpgp.model import sharded

    where = os.path.abspath(directory)

    def held(dask_worker: Any) -> int:
        actors = dask_worker.state.actors.values()
        return sum(isinstance(a, sharded.ShardServer) and a.directory == where for a in actors)

    return sum(client.run(held).values())


def test_fitting_again_lets_the_workers_drop_the_last_fits_shards(shard_dir, cluster):
    _, client = cluster
    model = dpgp.DPGP(iterations=1, seed=SEED, progress=False).fit(shard_dir, client=client)
    first = model._shard_link
    assert _loaded(client, shard_dir) >= N_SHARDS  # each shard read by a worker and kept
    model.fit(shard_dir, client=client)  # a new chain: the first link is closed
    assert first._loads == [] and model._shard_link is not first
    model._shard_link.close()
    assert _loaded(client, shard_dir) == 0
