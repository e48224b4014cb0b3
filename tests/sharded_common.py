"""What the sharded-fit tests share: a real ``distributed.LocalCluster`` with 2 worker processes
(one per test module that asks for it) and the check that two fits are the same chain."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import dpgp

SEED = 5


def assert_same_chain(a: dpgp.DPGP, b: dpgp.DPGP) -> None:
    np.testing.assert_array_equal(a.labels_, b.labels_)
    np.testing.assert_array_equal(a.length_scales_, b.length_scales_)
    assert a.alpha_ == b.alpha_
    assert a.history_["log_joint"] == b.history_["log_joint"]


@pytest.fixture(scope="module")
def cluster():
    distributed = pytest.importorskip("distributed")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cluster = distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0", silence_logs=50
        )
    client = distributed.Client(cluster)
    yield cluster, client
    client.close()
    cluster.close()
