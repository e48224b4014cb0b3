"""Ctrl-C during fits over shards (in subprocesses, each with its own ``LocalCluster`` where it
needs one): the state reached is kept, chains keep their finished blocks."""

from __future__ import annotations

import sys

import pytest

from conftest import interrupt_after

_CTRL_C = """
import signal, sys, threading, time
import dpgp

def main():
    signal.signal(signal.SIGINT, signal.default_int_handler)
    from distributed import Client, LocalCluster
    frames = dpgp.datasets.synthetic("highway", n_frames=400, seed=0)
    frames.to_parquet(sys.argv[1], shards=3)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                      silence_logs=50) as lc, Client(lc) as client:
        model = dpgp.DPGP(iterations=100000, progress=False, noise_var=0.5)

        def after_the_first_sweep():  # history_ is made afresh by fit
            while len((model.__dict__.get("history_") or {}).get("log_joint", ())) < 1:
                time.sleep(0.05)
            print("fitting", flush=True)

        threading.Thread(target=after_the_first_sweep, daemon=True).start()
        model.fit(sys.argv[1], client=client)
        print("sweeps", model.n_iter_, flush=True)
        print("predict", model.predict(frames[:3]).tolist(), flush=True)

if __name__ == "__main__":
    main()
"""


def test_ctrl_c_keeps_the_state_reached_on_a_cluster(tmp_path):
    """Ctrl-C during a fit on a cluster stops it as a local fit stops (between steps, the state
    reached kept), and the model it keeps predicts (its frames gathered from the workers)."""
    pytest.importorskip("distributed")

    script = tmp_path / "fit.py"
    script.write_text(_CTRL_C)
    # Ctrl-C 2 s after the first sweep (the script says "fitting" then), mid-sweep or between
    code, out, err, _ = interrupt_after([sys.executable, str(script), str(tmp_path / "shards")], 2.0, 180)
    assert code == 0, err
    assert "fit interrupted after" in err and "keeps the state reached" in err
    assert 1 <= int(out.split("sweeps")[1].split()[0]) < 100000
    assert "predict [" in out


_CHAINS_CTRL_C = """
import signal, sys, time
import dpgp

signal.signal(signal.SIGINT, signal.default_int_handler)
dpgp.datasets.synthetic("highway", n_frames=400, seed=0).to_parquet(sys.argv[1], shards=3)
print("fitting", flush=True)
t = time.perf_counter()
chains = dpgp.fit_chains(sys.argv[1], 2, iterations=100000, block=2, progress=False, noise_var=0.5)
print("sweeps", chains.n_sweeps, "stopped in", time.perf_counter() - t, flush=True)
print("patterns", chains.best_model().n_patterns_, flush=True)
"""


def test_ctrl_c_stops_chains_over_shards_and_keeps_their_blocks(tmp_path):
    """Ctrl-C during fit_chains over shards (the chains' leaders in threads of this process)
    stops every chain before its next sweep and keeps the blocks that had finished."""

    # after 10 s several 2-sweep blocks of each chain have finished
    code, out, err, waited = interrupt_after(
        [sys.executable, "-c", _CHAINS_CTRL_C, str(tmp_path / "shards")], 10.0, 120
    )
    assert code == 0, err
    assert "fit_chains interrupted (Ctrl-C)" in err and "keep every finished block" in err
    sweeps = int(out.split("sweeps")[1].split()[0])
    assert sweeps >= 2 and sweeps % 2 == 0  # whole blocks only
    assert "patterns" in out
    print(f"Ctrl-C to exit: {waited:.1f} s")
