"""The sharded fit's chain pinned bitwise (issue 33): digests of the labels, hyperparameters, α
and per-sweep history of a fit over 4 shards, recorded from the fit whose leader held every
frame's label, before the labels moved to the shards. Where the labels live must not change the
chain: the same digests in this process and (see ``test_sharded_fit.py``) on a cluster."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

import dpgp

N_FRAMES, N_SHARDS, ITERATIONS, SEED = 800, 4, 6, 7

#: Recorded from the leader-held fit (commit f456aa8), in-process shards.
EXPECTED = {
    "gibbs": "b6deb4f8c0f849918fb9fb3b",
    "map": "4674a90359443234e4a8ee9e",
}


def digest(model: dpgp.DPGP) -> str:
    h = hashlib.sha256()
    arrays = (
        np.asarray(model.labels_, dtype=np.int64),
        np.asarray(model.length_scales_, dtype=np.float64),
        np.asarray(model.pattern_noise_var_, dtype=np.float64),
        np.array([model.alpha_, model.noise_var_[0], model.noise_var_[1]], dtype=np.float64),
        np.asarray(model.history_["log_joint"], dtype=np.float64),
        np.asarray(model.history_["ari"], dtype=np.float64),
        np.asarray(model.history_["moves"], dtype=np.int64),
        np.asarray(model._sampler.split_merge_counts(), dtype=np.int64),
    )
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:24]


@pytest.fixture(scope="module")
def shard_dir(tmp_path_factory):
    directory = tmp_path_factory.mktemp("identity") / "frames"
    dpgp.datasets.synthetic("intersection", N_FRAMES, seed=11).to_parquet(directory, shards=N_SHARDS)
    return directory


@pytest.mark.parametrize("assignment", ["gibbs", "map"])
def test_sharded_chain_is_the_leader_held_chain_bitwise(shard_dir, assignment):
    model = dpgp.DPGP(iterations=ITERATIONS, seed=SEED, progress=False, checkpoint_every=2, assignment=assignment).fit(
        shard_dir
    )
    assert digest(model) == EXPECTED[assignment]
