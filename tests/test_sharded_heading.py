"""Fields over heading on Parquet shards (issue 34): the shards send each point's previous heading,
so a fit over heading runs over them, on a real ``distributed.LocalCluster`` as in this process;
its checkpoint resumes to the uninterrupted chain."""

from __future__ import annotations

import numpy as np
import pytest

import dpgp
from sharded_common import SEED, assert_same_chain, cluster  # noqa: F401  (a fixture)

# --- fields over heading on shards --------------------------------------------------------------
HEADED = dict(iterations=3, seed=SEED, progress=False, inputs="position+heading", likelihood="hsgp")


@pytest.fixture(scope="module")
def headed_dir(tmp_path_factory):
    """A two-way road's frames (they carry previous headings) in 2 shards."""
    from heading_roads import two_way_road

    frames = dpgp.make_frames(two_way_road(n_vehicles=30), dt=1.0)
    assert frames.prev_heading is not None
    directory = tmp_path_factory.mktemp("headed") / "frames"
    frames.to_parquet(directory, shards=2)
    return frames, directory


def test_fields_over_heading_fit_over_shards_on_a_cluster_as_in_process(headed_dir, cluster):
    """The shards send their points' previous headings: a fit over heading runs over them (no
    longer read into memory, no longer refused with client=), the same chain on the cluster's
    worker processes as in this process, and not the chain over position."""
    frames, directory = headed_dir
    here = dpgp.DPGP(**HEADED).fit(directory)
    assert here.inputs_ == "position+heading" and here._frames_dir is not None  # over the shards
    on_cluster = dpgp.DPGP(**HEADED).fit(directory, client=cluster[1])
    assert_same_chain(on_cluster, here)
    np.testing.assert_array_equal(on_cluster.heading_scales_, here.heading_scales_)
    blind = dpgp.DPGP(**{**HEADED, "inputs": "position"}).fit(directory)
    assert blind.history_["log_joint"] != here.history_["log_joint"]  # the headings were used
    scores = on_cluster.score_samples(frames)
    assert scores.shape == (len(frames),) and np.all(np.isfinite(scores))
    auto = dpgp.DPGP(**{**HEADED, "inputs": "auto"}).fit(directory)
    assert "no previous headings" not in auto.engine_choice_["inputs"]["why"]  # the shards have them


def test_a_fit_over_heading_on_one_shard_is_the_chain_over_the_frames_in_memory(headed_dir, tmp_path):
    """The headings the shard sends are the frames' own: on one shard, the sub-cluster chain over
    heading is the in-memory one, sweep for sweep."""
    frames, _ = headed_dir
    frames.to_parquet(tmp_path / "one", shards=1)
    kw = {**HEADED, "sampler": "subcluster"}
    over_shard = dpgp.DPGP(**kw).fit(tmp_path / "one")
    assert over_shard._frames_dir is not None
    assert_same_chain(over_shard, dpgp.DPGP(**kw).fit(frames))


def test_a_checkpoint_of_a_fit_over_heading_on_shards_resumes_to_the_same_chain(headed_dir, tmp_path):
    """The checkpoint leaves the frames, headings with them, in their shards (no frame_prev_heading
    in the file), and the chain resumed from it is the uninterrupted one; the finished model saves
    and loads with the headings it gathered."""
    _, directory = headed_dir
    kw = {**HEADED, "checkpoint_every": 2}
    full = dpgp.DPGP(**{**kw, "iterations": 6}).fit(directory)
    dpgp.DPGP(**{**kw, "iterations": 4, "checkpoint": str(tmp_path / "c.ckpt")}).fit(directory)
    with np.load(tmp_path / "c.ckpt") as archive:
        assert "frame_prev_heading" not in archive.files and "heading_scales" in archive.files
    resumed = dpgp.DPGP.resume(tmp_path / "c.ckpt", iterations=6)
    assert resumed.inputs_ == "position+heading"
    assert_same_chain(resumed, full)
    full.save(tmp_path / "m.npz")
    loaded = dpgp.DPGP.load(tmp_path / "m.npz")
    np.testing.assert_array_equal(loaded.score_samples(headed_dir[0]), full.score_samples(headed_dir[0]))


# --- checkpoints of a fit over shards ----------------------------------------------------------
