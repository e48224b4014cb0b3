"""Ctrl-C ends a chains fit within seconds wherever it lands, and keeps every block the driver
had received (issue 37): before the workers exist, while they import dpgp, during the first
block, during a later block and (local processes) while a block's result is half sent; on local
worker processes and on a Dask LocalCluster of worker processes (here at two moments: one before
any block, one after some; a cluster's start and close cost seconds). Each moment is reached by
waiting for its trace marker (tests/chains/ctrl_c.py), never by sleeping; ``benches/ctrl_c.py``
runs every moment on both 20 times, beside a load."""

import signal

import pytest

from dpgp.chains._interrupt import Interrupts

import ctrl_c

CASES = [(p, "local") for p in ctrl_c.POINTS] + [("import", "dask"), ("a block", "dask")]


@pytest.mark.parametrize(("point", "backend"), CASES)
def test_ctrl_c_ends_the_fit_within_seconds_and_keeps_every_received_block(point, backend):
    if backend == "dask":
        pytest.importorskip("distributed")
    out = ctrl_c.run(point, backend)
    assert not ctrl_c.problems(out), (ctrl_c.problems(out), "\n".join(out.lines[-40:]))


def test_a_ctrl_c_while_the_driver_is_busy_is_raised_at_its_next_wait_once():
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a terminal
    try:
        with Interrupts() as interrupts:
            signal.raise_signal(signal.SIGINT)  # busy (submitting, storing a block): remembered
            assert interrupts.pending
            with pytest.raises(KeyboardInterrupt), interrupts.interruptible():
                pass
            interrupts.handled()
            with interrupts.interruptible():
                pass  # handled: not raised again
            with pytest.raises(KeyboardInterrupt), interrupts.interruptible():
                signal.raise_signal(signal.SIGINT)  # waiting: raised at once
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, previous)
