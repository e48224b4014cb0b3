"""dpgp.fit_chains on a real dask.distributed LocalCluster with 2 worker processes: 4 chains run,
the result equals local processes with the same seed, and a worker killed mid-run fails its
chains by name while the others are kept."""

import os
import signal
import threading
import time
import warnings

import numpy as np
import pytest

import dpgp

distributed = pytest.importorskip("distributed")
dask = pytest.importorskip("dask")

SETTINGS = dict(iterations=12, block=4, seed=5, progress=False)


@pytest.fixture(scope="module")
def frames():
    return dpgp.datasets.synthetic("intersection", n_frames=60, seed=0)


def _cluster(**config):
    with dask.config.set(config), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "port 8787 in use" when a second cluster starts
        cluster = distributed.LocalCluster(
            n_workers=2,
            processes=True,
            threads_per_worker=1,
            dashboard_address=None,
            worker_dashboard_address=None,
            silence_logs=50,
        )
    return cluster, distributed.Client(cluster)


@pytest.fixture(scope="module")
def cluster():
    cluster, client = _cluster()
    yield cluster, client
    client.close()
    cluster.close()


def test_four_chains_on_dask_equal_local_processes(frames, cluster):
    client = cluster[1]
    assert len(client.scheduler_info()["workers"]) == 2
    on_dask = dpgp.fit_chains(frames, 4, client=client, **SETTINGS)
    local = dpgp.fit_chains(frames, 4, **SETTINGS)
    assert on_dask.names == local.names == ["chain0", "chain1", "chain2", "chain3"]
    np.testing.assert_array_equal(on_dask.labels, local.labels)
    for q in ("log_joint", "n_patterns", "alpha", "moves"):
        np.testing.assert_array_equal(on_dask.traces[q], local.traces[q])
    np.testing.assert_array_equal(on_dask.point_estimate().labels, local.point_estimate().labels)


def test_cli_runs_chains_on_a_scheduler_address(frames, cluster, tmp_path, capsys):
    from dpgp import cli

    data = tmp_path / "frames.csv"
    frames.to_pandas().to_csv(data, index=False)
    out = tmp_path / "m.npz"
    args = ["fit", str(data), "-o", str(out), "--chains", "2", "--iterations", "6", "--no-progress"]
    assert cli.main([*args, "--scheduler", cluster[0].scheduler_address]) == 0
    assert "Chains(2 chains × 6 sweeps" in capsys.readouterr().out
    local = dpgp.fit_chains(frames, 2, iterations=6, seed=0, progress=False)
    np.testing.assert_array_equal(dpgp.DPGP.load(out).labels_, local.best_model().labels_)


def test_a_killed_worker_fails_its_chains_by_name_and_keeps_the_others(frames):
    # With allowed-failures 0 the scheduler gives up on a task at the first worker death
    # (by default it would retry it elsewhere, and the chain would survive).
    cluster, client = _cluster(**{"distributed.scheduler.allowed-failures": 0})
    victims: dict[str, list[str]] = {}
    try:
        pids = client.run(os.getpid)

        def kill_mid_run() -> None:
            deadline = time.time() + 60
            while time.time() < deadline:
                busy = {w: list(keys) for w, keys in client.processing().items() if keys}
                running = [w for w, keys in busy.items() if any("block1" in str(k) for k in keys)]
                if running:
                    w = running[0]
                    victims[w] = [str(k) for k in busy[w]]
                    os.kill(pids[w], signal.SIGKILL)
                    return
                time.sleep(0.02)

        killer = threading.Thread(target=kill_mid_run)
        killer.start()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            ch = dpgp.fit_chains(frames, 4, client=client, **{**SETTINGS, "iterations": 10, "block": 2})
        killer.join()
    finally:
        client.close()
        cluster.close()
    assert victims, "no block was seen running"
    assert ch.failures_, "the killed worker's chain was not reported"
    for name, error in ch.failures_.items():
        assert "KilledWorker" in error
        assert any(name + "-" in key for keys in victims.values() for key in keys)
        assert any(name in str(w.message) for w in caught)
    assert sorted(ch.names + list(ch.failures_)) == ["chain0", "chain1", "chain2", "chain3"]
    assert ch.n_sweeps == 10  # the survivors ran to the end ...
    local = dpgp.fit_chains(frames, 4, **{**SETTINGS, "iterations": 10, "block": 2})
    for name in ch.names:  # ... exactly as undisturbed chains do
        i, j = ch.names.index(name), local.names.index(name)
        np.testing.assert_array_equal(ch.labels[i], local.labels[j])
