"""Ctrl-C during a fit stops between frames and keeps the state reached."""

from __future__ import annotations

import sys

from conftest import interrupt_after

SCRIPT = """
import signal
import dpgp
# A background job may inherit SIGINT as ignored; restore Python's default (KeyboardInterrupt).
signal.signal(signal.SIGINT, signal.default_int_handler)
frames = dpgp.datasets.synthetic("highway", n_frames=150, seed=0)
model = dpgp.DPGP(iterations=100000, progress=False, noise_var={noise}{extra})
print("fitting", flush=True)
model.fit(frames)
print("sweeps", model.n_iter_, "patterns", model.n_patterns_, flush=True)
print("predict", model.predict(frames[:3]).tolist(), flush=True)
"""


def test_ctrl_c_keeps_the_state_reached():
    # A given noise and engine: no pilot fits and no accuracy probe of likelihood="auto" (five
    # initialisations, several seconds on a loaded machine), so sweeps start at once.
    script = SCRIPT.format(noise=0.5, extra=', likelihood="hsgp"')
    # initialisation takes well under a second: after 6 s sweeps are under way
    code, out, err, _ = interrupt_after([sys.executable, "-c", script], 6.0, 120)
    assert code == 0, err
    assert "fit interrupted after" in err and "keeps the state reached" in err
    sweeps = int(out.split("sweeps")[1].split()[0])
    assert 1 <= sweeps < 100000
    assert "predict [" in out


def test_ctrl_c_during_the_noise_pilots_stops_the_fit():
    """noise_var="auto" runs short pilot fits first; Ctrl-C there ends the fit (there is no
    state to keep yet) instead of being taken as the end of one pilot."""
    script = SCRIPT.format(noise=repr("pilot"), extra="")
    code, out, err, waited = interrupt_after([sys.executable, "-c", script], 1.0, 60)  # the pilots take seconds
    assert code != 0 and "KeyboardInterrupt" in err, (out, err)
    assert "sweeps" not in out
    assert waited < 30


SHARDED = """
import signal, sys
import dpgp
signal.signal(signal.SIGINT, signal.default_int_handler)
frames = dpgp.datasets.synthetic("highway", n_frames=400, seed=0)
frames.to_parquet(sys.argv[1], shards=3)
model = dpgp.DPGP(iterations=100000, progress=False, noise_var=0.5)
print("fitting", flush=True)
model.fit(sys.argv[1])
print("sweeps", model.n_iter_, "patterns", model.n_patterns_, flush=True)
print("predict", model.predict(frames[:3]).tolist(), flush=True)
"""


def test_ctrl_c_keeps_the_state_reached_over_shards(tmp_path):
    """A chain over shards (in this process) stops at Ctrl-C as a local one does, and the model
    it keeps predicts (its frames gathered from the shards)."""
    code, out, err, _ = interrupt_after([sys.executable, "-c", SHARDED, str(tmp_path / "shards")], 6.0, 120)
    assert code == 0, err
    assert "fit interrupted after" in err and "keeps the state reached" in err
    sweeps = int(out.split("sweeps")[1].split()[0])
    assert 1 <= sweeps < 100000
    assert "predict [" in out
