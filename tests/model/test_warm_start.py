"""``DPGP.fit(frames, warm_start=True)``: the one sweep loop continues a fitted chain. The oracle is
the uninterrupted chain: a fit of 10 sweeps continued by 10 more is bitwise a fit of 20 (same
sampler, same random stream, the canonical rebuilds at the same sweeps)."""

from __future__ import annotations

import numpy as np
import pytest

import dpgp

SETTINGS = dict(seed=4, progress=False, noise_var=0.49, store_labels=True, posterior_draws=8)


@pytest.fixture(scope="module")
def frames():
    return dpgp.datasets.synthetic("intersection", n_frames=50, seed=2)


@pytest.mark.parametrize("extra", [{}, {"likelihood": "hsgp", "split_merge": 1}])
def test_continuing_equals_the_longer_fit(frames, extra):
    long = dpgp.DPGP(iterations=20, **SETTINGS, **extra).fit(frames)
    model = dpgp.DPGP(iterations=10, **SETTINGS, **extra).fit(frames)
    assert model.fit(frames, warm_start=True) is model
    assert model.n_iter_ == 20 and model.iterations == 10  # the setting is left as given
    np.testing.assert_array_equal(model.labels_, long.labels_)
    np.testing.assert_array_equal(model.length_scales_, long.length_scales_)
    np.testing.assert_array_equal(model.label_trace_, long.label_trace_)
    for key in ("log_joint", "alpha", "n_patterns", "moves", "ari"):
        assert model.history_[key] == long.history_[key], key
    assert model.alpha_ == long.alpha_
    np.testing.assert_array_equal(model.predict_proba(frames[:5]), long.predict_proba(frames[:5]))


def test_a_continued_chain_differs_from_a_restart(frames):
    model = dpgp.DPGP(iterations=6, **SETTINGS).fit(frames)
    restart = dpgp.DPGP(iterations=6, **SETTINGS).fit(frames).fit(frames)
    model.fit(frames, warm_start=True)
    assert len(model.history_["log_joint"]) == 12 and len(restart.history_["log_joint"]) == 6


def test_warm_start_on_an_unfitted_model_is_a_fit(frames):
    a = dpgp.DPGP(iterations=5, **SETTINGS).fit(frames, warm_start=True)
    b = dpgp.DPGP(iterations=5, **SETTINGS).fit(frames)
    np.testing.assert_array_equal(a.label_trace_, b.label_trace_)


def test_other_frames_are_refused(frames):
    model = dpgp.DPGP(iterations=3, **SETTINGS).fit(frames)
    with pytest.raises(dpgp.InvalidInputError, match="frames the model was fitted to"):
        model.fit(frames[:20], warm_start=True)
    same = dpgp.Frames(frames.ids.copy(), frames.offsets.copy(), frames.xy.copy(), frames.v.copy())
    model.fit(same, warm_start=True)  # equal frames, another object: continues
    assert model.n_iter_ == 6


def test_a_loaded_model_continues(frames, tmp_path):
    model = dpgp.DPGP(iterations=5, **SETTINGS).fit(frames)
    model.save(tmp_path / "m.npz")
    loaded = dpgp.DPGP.load(tmp_path / "m.npz")
    loaded.fit(frames, warm_start=True)
    assert loaded.n_iter_ == 10 and len(loaded.history_["log_joint"]) == 10 and loaded.label_trace_.shape == (10, 50)
    assert loaded.history_["log_joint"][:5] == model.history_["log_joint"]
