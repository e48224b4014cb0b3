"""φ (vehicle count per frame) and ψ (positions over a grid of bins): densities, sampling,
storage without pickle, and bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import dpgp

from distributions_oracle import cv_oracle, smoothed_oracle

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"


def toy_frames() -> dpgp.Frames:
    # 4 frames with 1, 2, 2, 3 vehicles; positions chosen to fill known bins of (0,4)x(0,2)
    frame = [0, 1, 1, 2, 2, 3, 3, 3]
    x = [0.5, 0.5, 1.5, 3.5, 3.5, 0.2, 3.9, 4.0]
    y = [0.5, 0.5, 1.5, 1.5, 0.5, 0.1, 1.9, 2.0]
    return dpgp.Frames.from_arrays(frame, x, y, np.zeros(8), np.zeros(8))


def test_count_pmf_is_the_empirical_distribution():
    d = dpgp.EmpiricalDistributions.from_frames(toy_frames(), roi=(0, 4, 0, 2), bins=(4, 2), pseudocount=0)
    assert d.is_paper_form
    assert np.allclose(d.count_pmf(), [0, 0.25, 0.5, 0.25])
    assert d.max_count == 3
    assert d.log_count_pmf(2) == pytest.approx(np.log(0.5))
    assert np.array_equal(d.log_count_pmf([4, 17]), [-np.inf] * 2)  # the paper's form: unseen counts
    with pytest.raises(dpgp.InvalidInputError, match="whole numbers"):
        d.log_count_pmf(1.5)
    with pytest.raises(dpgp.InvalidInputError, match="at least 1"):  # a frame holds a vehicle
        d.log_count_pmf([0, 2])


def test_position_density_is_a_histogram_uniform_in_each_bin():
    d = dpgp.EmpiricalDistributions.from_frames(toy_frames(), roi=(0, 4, 0, 2), bins=(4, 2), pseudocount=0)
    # bins are 1 x 1; 8 positions: bin (0,0) holds 3 (0.5,0.5 twice and 0.2,0.1), bin (3,1) holds 3
    # (3.5,1.5; 3.9,1.9; and 4.0,2.0 on the upper edge), (1,1) and (3,0) one each
    expect = np.zeros((4, 2))
    expect[0, 0], expect[3, 1], expect[1, 1], expect[3, 0] = 3, 3, 1, 1
    assert np.array_equal(d.position_hist, expect)
    got = np.exp(d.log_position_density([[0.01, 0.01], [0.99, 0.99], [1.5, 1.2], [2.5, 0.5], [-0.1, 0.5], [2, 2.01]]))
    assert np.allclose(got, [3 / 8, 3 / 8, 1 / 8, 0, 0, 0])
    # a density: integrates to 1 over the ROI (sum of bin density times bin area)
    centres = np.array([[i + 0.5, j + 0.5] for i in range(4) for j in range(2)])
    assert np.exp(d.log_position_density(centres)).sum() * 1.0 == pytest.approx(1.0)
    assert d.log_frame_density([[0.5, 0.5], [3.5, 1.5]]) == pytest.approx(np.log(0.5) + 2 * np.log(3 / 8))


def test_sampling_follows_the_distributions():
    d = dpgp.EmpiricalDistributions.from_frames(toy_frames(), roi=(0, 4, 0, 2), bins=(4, 2))
    counts = d.sample_counts(40_000, rng=1)
    assert counts.dtype == np.int64
    freq = np.bincount(counts, minlength=4) / len(counts)
    assert np.allclose(freq, [0, 0.25, 0.5, 0.25], atol=0.01)
    xy = d.sample_positions(40_000, rng=np.random.default_rng(2))
    assert xy.shape == (40_000, 2)
    assert xy[:, 0].min() >= 0 and xy[:, 0].max() <= 4 and xy[:, 1].min() >= 0 and xy[:, 1].max() <= 2
    hist, _, _ = np.histogram2d(xy[:, 0], xy[:, 1], bins=(4, 2), range=((0, 4), (0, 2)))
    assert np.allclose(hist / len(xy), d.position_hist / 8, atol=0.01)
    assert hist[2].sum() == 0  # an empty bin is never sampled
    # uniform inside a bin: inside bin (0, 0) the mean is its centre
    inside = xy[(xy[:, 0] < 1) & (xy[:, 1] < 1)]
    assert np.allclose(inside.mean(axis=0), [0.5, 0.5], atol=0.02)
    # reproducible from a seed
    assert np.array_equal(d.sample_positions(5, rng=7), d.sample_positions(5, rng=7))


@pytest.mark.parametrize("pseudocount", [1.0, (0.3, 2.0)])
def test_smoothed_densities_match_the_formula(pseudocount):
    a_count, a_position = np.broadcast_to(pseudocount, (2,))
    f = toy_frames()
    d = dpgp.EmpiricalDistributions.from_frames(f, roi=(0, 4, 0, 2), bins=(4, 2), pseudocount=pseudocount)
    assert d.pseudocount == (a_count, a_position) and not d.is_paper_form
    assert np.allclose(d.count_pmf(), [0, 0.25, 0.5, 0.25])  # scenarios are drawn from the recorded φ
    log_phi, log_psi = smoothed_oracle(f.sizes, f.xy, (0, 4, 0, 2), (4, 2), a_count, a_position)
    counts = [1, 2, 3, 4, 7, 40]
    assert np.allclose(d.log_count_pmf(counts), [log_phi(l) for l in counts])
    pts = np.array([[0.5, 0.5], [2.5, 0.5], [3.99, 1.99], [4.5, 0.5], [-3.0, 1.0], [5.0, -2.5], [2.0, 9.0]])
    assert np.allclose(d.log_position_density(pts), [log_psi(x, y) for x, y in pts])
    for frame in ([[0.5, 0.5], [2.5, 0.5]], [[4.5, 3.0]] * 5):
        want = log_phi(len(frame)) + sum(log_psi(x, y) for x, y in frame)
        assert d.log_frame_density(frame) == pytest.approx(want)
    assert np.allclose(d.log_frame_densities(f), [d.log_frame_density(fr.xy) for fr in f])


def test_smoothed_densities_are_normalised_and_finite_beyond_the_roi():
    d = dpgp.EmpiricalDistributions.from_frames(toy_frames(), roi=(0, 4, 0, 2), bins=(4, 2), pseudocount=(0.7, 0.4))
    assert np.exp(d.log_count_pmf(np.arange(1, 200))).sum() == pytest.approx(1.0)
    # ψ̃ integrates to 1 over the plane: midpoints of a fine grid reaching 30 bin widths beyond
    h = 0.02
    xs, ys = np.arange(-30, 34, h) + h / 2, np.arange(-30, 32, h) + h / 2
    total = 0.0
    for x in np.array_split(xs, 16):
        gx, gy = np.meshgrid(x, ys, indexing="ij")
        total += np.exp(d.log_position_density(np.c_[gx.ravel(), gy.ravel()])).sum() * h * h
    assert total == pytest.approx(1.0, abs=1e-4)
    far = d.log_position_density([[4.5, 1.0], [40.0, 1.0], [1e99, -1e99], [6e6, 6e6]])
    assert np.all(np.isfinite(far)) and np.all(np.diff(far[:3]) < 0)  # a penalty that grows with distance
    assert np.isfinite(d.log_count_pmf(10**15))


def test_paper_form_is_scored_smoothed_by_a_half():
    """The paper's unsmoothed form (model files before issue 36) scores held-out frames with the
    pseudo-count ½ dpgp used then, finite beyond the ROI too."""
    d = dpgp.EmpiricalDistributions.from_frames(toy_frames(), roi=(0, 4, 0, 2), bins=(4, 2), pseudocount=0)
    assert d.is_paper_form and d.for_scoring().pseudocount == (0.5, 0.5)
    log_phi, log_psi = smoothed_oracle(toy_frames().sizes, toy_frames().xy, (0, 4, 0, 2), (4, 2), 0.5, 0.5)
    for frame in ([[0.5, 0.5], [2.5, 0.5]], [[0.5, 0.5]] * 4, [[2.5, 0.5]] * 6, [[0.5, 0.5], [4.5, 0.5]]):
        want = log_phi(len(frame)) + sum(log_psi(x, y) for x, y in frame)
        assert d.held_out_log_density(frame) == pytest.approx(want)
    smoothed = dpgp.EmpiricalDistributions.from_frames(toy_frames(), roi=(0, 4, 0, 2), bins=(4, 2), pseudocount=2.0)
    assert smoothed.for_scoring() is smoothed


@pytest.mark.parametrize("seed", [0, 1])
def test_auto_pseudocounts_are_the_blocked_cross_validation_optimum(seed):
    frames = dpgp.datasets.synthetic("intersection", n_frames=23, seed=seed, vehicles=(1, 6))
    roi, bins = frames.bounds(), (5, 4)
    d = dpgp.EmpiricalDistributions.from_frames(frames, roi=roi, bins=bins)
    assert d.pseudocount == pytest.approx(cv_oracle(frames, roi, bins), rel=1e-12)
    one = dpgp.EmpiricalDistributions.from_frames(frames[:1], bins=bins)  # nothing to hold out
    assert one.pseudocount == (0.5, 0.5)


def test_storage_as_plain_arrays(tmp_path):
    d = dpgp.EmpiricalDistributions.from_frames(toy_frames(), roi=(0, 4, 0, 2), bins=(4, 2), pseudocount=(0.5, 2.0))
    stored = d.to_dict()
    assert all(isinstance(v, np.ndarray) and v.dtype != object for v in stored.values())
    np.savez(tmp_path / "m.npz", **stored)
    with np.load(tmp_path / "m.npz", allow_pickle=False) as z:
        back = dpgp.EmpiricalDistributions.from_dict(dict(z))
    pts = np.random.default_rng(0).uniform([0, 0], [4, 2], (50, 2))
    assert np.array_equal(back.log_position_density(pts), d.log_position_density(pts))
    assert np.array_equal(back.count_pmf(), d.count_pmf()) and back.roi == d.roi and back.bins == d.bins
    assert back.pseudocount == (0.5, 2.0)
    # written before issue 36: no pseudo-counts, or the one scalar then stored (0 by default)
    before = {k: v for k, v in stored.items() if not k.endswith("_pseudocount")}
    assert dpgp.EmpiricalDistributions.from_dict(before).is_paper_form
    assert dpgp.EmpiricalDistributions.from_dict({**before, "pseudocount": np.array(0.0)}).is_paper_form
    assert dpgp.EmpiricalDistributions.from_dict({**before, "pseudocount": np.array(1.5)}).pseudocount == (1.5, 1.5)
    as_lists = {k: v.tolist() for k, v in stored.items()}  # e.g. from JSON
    assert dpgp.EmpiricalDistributions.from_dict(as_lists).roi == d.roi
    with pytest.raises(dpgp.DataFormatError, match="newer"):
        dpgp.EmpiricalDistributions.from_dict({**stored, "version": np.array(99)})
    with pytest.raises(dpgp.DataFormatError, match="missing"):
        dpgp.EmpiricalDistributions.from_dict({"roi": stored["roi"]})


def test_roi_defaults_to_make_frames_crop():
    import pandas as pd

    t = np.arange(0, 5.01, 0.5)
    tracks = pd.DataFrame(
        {"track": np.repeat([0, 1], len(t)), "t": np.r_[t, t], "x": np.r_[t * 2, 10 - t], "y": np.r_[t, t * 0 + 1]}
    )
    frames = dpgp.make_frames(tracks, roi=(0, 8, 0, 4), dt=0.5, units="ft->m")
    d = dpgp.EmpiricalDistributions.from_frames(frames, bins=3)
    assert d.roi == pytest.approx((0, 8 * 0.3048, 0, 4 * 0.3048)) and d.bins == (3, 3)
    plain = dpgp.EmpiricalDistributions.from_frames(frames[:])  # a slice has no summary: bounding box
    assert plain.roi == pytest.approx(frames.bounds())


def test_real_us101_counts():
    path = DATA / "ngsim_us101_frames.tsv"
    if not path.exists():
        pytest.skip(f"real data file {path} is absent (it lives in ../shared/data beside the repo)")
    frames = dpgp.read_frames(path)
    d = dpgp.EmpiricalDistributions.from_frames(frames, bins=(6, 20))
    pmf = d.count_pmf()
    # 7-30 vehicles per frame in this file (its README says 8-19)
    assert np.flatnonzero(pmf)[0] == 7 and d.max_count == 30
    assert np.allclose(pmf, np.bincount(frames.sizes) / len(frames)) and pmf.sum() == pytest.approx(1.0)
    assert np.all(np.isfinite(d.log_position_density(frames.xy)))


def test_bad_input():
    f = toy_frames()
    with pytest.raises(dpgp.InvalidInputError, match="outside the roi"):
        dpgp.EmpiricalDistributions.from_frames(f, roi=(0, 1, 0, 1))
    for roi in ((1, 0, 0, 1), (0, 1, 0), "everywhere"):
        with pytest.raises(dpgp.InvalidInputError, match="roi must be"):
            dpgp.EmpiricalDistributions.from_frames(f, roi=roi)
    for bins in (0, (3, 0), (2.5, 2), (1, 2, 3)):
        with pytest.raises(dpgp.InvalidInputError, match="bins"):
            dpgp.EmpiricalDistributions.from_frames(f, bins=bins)
    d = dpgp.EmpiricalDistributions.from_frames(f)
    with pytest.raises(dpgp.ShapeError):
        d.log_position_density([1.0, 2.0, 3.0])
    with pytest.raises(dpgp.InvalidInputError, match="non-finite"):
        d.log_position_density([[np.nan, 1.0]])
    with pytest.raises(dpgp.InvalidInputError, match="whole number"):
        d.sample_counts(-1)
    for bad in (-1, np.nan, (1.0, 2.0, 3.0), "x", (0.5, np.inf), 1.1e100):  # 1e308: totals overflowed (fuzz)
        with pytest.raises(dpgp.InvalidInputError, match="pseudocount"):
            dpgp.EmpiricalDistributions.from_frames(f, pseudocount=bad)
    with pytest.raises(dpgp.InvalidInputError, match="whole numbers"):
        d.log_count_pmf(np.inf)
    for extreme in (5e-324, 1e100):  # a tiny pseudo-count over the totals must not underflow to -inf
        e = dpgp.EmpiricalDistributions.from_frames(f, pseudocount=extreme)
        assert np.isfinite(e.log_position_density([[0.5, 0.5], [2.5, 0.5], [9.0, 9.0]])).all()
        assert np.isfinite(e.log_count_pmf([1, 2, 50])).all()


def test_stored_histograms_that_overflow_or_hold_no_vehicles_are_refused():
    d = dpgp.EmpiricalDistributions.from_frames(toy_frames()).to_dict()
    with pytest.raises(dpgp.InvalidInputError, match="overflow"):
        dpgp.EmpiricalDistributions.from_dict({**d, "count_hist": [1e308, 1e308]})
    with pytest.raises(dpgp.InvalidInputError, match="empty"):
        dpgp.EmpiricalDistributions.from_dict({**d, "count_hist": [5.0, 0.0, 0.0]})
