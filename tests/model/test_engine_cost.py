"""likelihood="auto" by predicted cost (dpgp.engine_cost): the rule on constructed cases, and that
auto's fit is bitwise the fit of the engine it picks."""

from __future__ import annotations

import numpy as np
import pytest

import dpgp
from dpgp.model import engine_cost as ec


def test_features_are_the_documented_sums():
    n, frames = [10, 200, 3000], [3, 4]  # points per pattern; vehicles per frame
    np.testing.assert_array_equal(
        ec.features("exact", n, frames), [25, 100 + 40_000 + 9_000_000, 1000 + 8_000_000 + 27_000_000_000]
    )
    s = np.minimum(n, 500)  # a pattern smaller than the basis uses its dense n x n factor
    np.testing.assert_array_equal(
        ec.features("hsgp", n, frames, 500), [500 * 25, (np.array(n) * s**2).sum(), (s**3).sum(), 500 * (100 + 40_000)]
    )
    with pytest.raises(ValueError):
        ec.features("hsgp", n, frames)
    with pytest.raises(ValueError):
        ec.features("vecchia", n, frames)


def test_rule_on_constructed_cases(monkeypatch):
    monkeypatch.setattr(ec, "COEFFICIENTS", {"exact": (1e-6, 0.0, 1e-9), "hsgp": (1e-7, 1e-9, 1e-9, 0.0)})
    M = 400
    # tiny data: exact's worst case (one pattern of 300 points) beats hsgp's least cost: exact, no probe
    c = ec.choose_upfront([10] * 30, M, None)
    assert c is not None and c.engine == "exact" and c.sizes_from == "worst case"
    # exact's worst case is slower: the sizes must be predicted first
    many = [10] * 2000
    assert ec.choose_upfront(many, M, None) is None
    # many small patterns: exact is cheaper (Σ n³ small)
    small = ec.choose([500] * 40, many, M, None)
    assert small.engine == "exact" and small.exact_seconds < small.hsgp_seconds
    # hsgp predicted faster, but by less than the margin: exact (the model, not its approximation)
    near = ec.choose([1000] * 20, many, M, None)
    assert near.hsgp_seconds < near.exact_seconds <= ec.HSGP_MARGIN * near.hsgp_seconds and near.engine == "exact"
    # one large pattern: its n³ makes exact the slower one
    big = ec.choose([19_000, 500, 500], many, M, None)
    assert big.engine == "hsgp" and big.exact_seconds > big.hsgp_seconds
    # the switch happens where the predictions cross
    sizes = np.arange(100, 6000, 50)
    picks = [ec.choose([n], many, M, None).engine for n in sizes]
    cross = [
        ec.sweep_seconds("exact", [n], many) <= ec.HSGP_MARGIN * ec.sweep_seconds("hsgp", [n], many, M) for n in sizes
    ]
    assert picks == ["exact" if x else "hsgp" for x in cross] and "exact" in picks and "hsgp" in picks
    # memory: exact needs its peak (every point in one pattern, with candidate copies) within the
    # budget, not just the largest initial pattern's factors
    assert ec.choose([500] * 40, many, M, ec.exact_peak_bytes(20_000) - 1).engine == "hsgp"
    assert ec.choose([500] * 40, many, M, ec.exact_peak_bytes(20_000)).engine == "exact"
    assert ec.choose([500] * 40, many, M, 100 * ec.exact_bytes(500)).engine == "hsgp"
    assert ec.choose_upfront([10] * 30, M, ec.exact_peak_bytes(300) - 1) is None


def test_sumo_junction_sizes_no_longer_pick_exact():
    """All 3,150 SUMO junction frames (23,936 points): hsgp was faster, but the accuracy probe
    (gap 0.29 nats per point) sent the fit to exact, since its initial patterns' factors fitted a
    12.3 GB budget; the exact chain then stopped mid-fit needing 12.5 GB."""
    sizes = [2751, 2541, 1998, 1858, 1635, 1442] + [1000] * 11 + [711]
    assert sum(sizes) == 23_936 and 6 * ec.exact_bytes(max(sizes)) < 12.3e9
    c = ec.choose(sizes, [8] * 2992, 484, int(12.3e9))
    assert c.engine == "hsgp" and not c.exact_fits
    assert ec.check_accuracy(c, 0.29).engine == "hsgp"
    # the same data under a budget that holds exact's peak: the probe sends it to exact
    roomy = ec.choose(sizes, [8] * 2992, 484, ec.exact_peak_bytes(23_936))
    assert roomy.exact_fits and ec.check_accuracy(roomy, 0.29).engine == "exact"


def test_exact_bytes_matches_the_growing_buffers():
    # the core's factor::capacity: n + n/4, at least 16, rounded up to a multiple of 16
    assert ec.exact_bytes(1000) == 8 * 2 * 1264**2
    assert ec.exact_bytes(1024) == 8 * 2 * 1280**2
    assert ec.exact_bytes(1025) == 8 * 2 * 1296**2
    assert ec.exact_bytes(3) == 8 * 2 * 16**2


def _same_fit(a, b):
    np.testing.assert_array_equal(a.labels_, b.labels_)
    assert a.history_["log_joint"] == b.history_["log_joint"]
    np.testing.assert_array_equal(a.length_scales_, b.length_scales_)


@pytest.mark.parametrize("winner", ["exact", "hsgp"])
def test_auto_after_the_probe_is_the_engine_it_picks(monkeypatch, winner):
    """Undecided up front, auto initialises hsgp, predicts both engines from its pattern sizes and
    runs the winner: bitwise the explicit engine's fit (never a switch mid-chain)."""
    frames = dpgp.datasets.synthetic("intersection", n_frames=50, seed=4)
    kw = dict(
        iterations=3, noise_var=0.5, length_scale_prior=(10.0, 1.0), seed=7, progress=False, posterior_draws=2,
        sampler="collapsed",  # the rule between the collapsed sampler's engines (the sub-cluster one: below)
    )  # fmt: skip
    n = frames.n_points
    if winner == "exact":
        # exact pays n³, hsgp a flat half of exact's worst case per frame: exact is slower for one
        # pattern of every point (so auto probes) and faster on the probe's several patterns
        m = dpgp.hsgp.basis_for(frames.xy, (10.0, 1.0)).size  # the basis the fit sizes
        flat = 0.5e-9 * n**3 / ec.HSGP_MARGIN / ec.features("hsgp", [], frames.sizes, m)[0]
        coefficients = {"exact": (0.0, 0.0, 1e-9), "hsgp": (flat, 0.0, 0.0, 0.0)}
    else:  # exact's per-frame cost dwarfs hsgp's, whatever the sizes
        coefficients = {"exact": (1.0, 0.0, 0.0), "hsgp": (1e-9, 0.0, 0.0, 0.0)}
    monkeypatch.setattr(ec, "COEFFICIENTS", coefficients)
    auto = dpgp.DPGP(**kw).fit(frames)
    assert auto.engine_choice_["sizes_from"] == "hsgp initialisation"
    assert auto.likelihood_ == winner
    explicit = dpgp.DPGP(likelihood=winner, **kw).fit(frames)
    _same_fit(auto, explicit)
    assert auto.basis_ == explicit.basis_


def test_choice_is_saved_with_the_model(tmp_path):
    frames = dpgp.datasets.synthetic("highway", n_frames=20, seed=1)
    m = dpgp.DPGP(iterations=1, noise_var=1.0, progress=False).fit(frames)
    m.save(tmp_path / "m.npz")
    back = dpgp.DPGP.load(tmp_path / "m.npz")
    assert back.engine_choice_ == m.engine_choice_ and back.engine_choice_["engine"] == "exact"


def _gp_draw(w: float, n: int = 300, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Velocities of a squared-exponential GP (length scale ``w``, unit variance, noise 0.01) at
    ``n`` positions on a 40 x 40 square (dense enough for short length scales to show): a numpy
    draw, independent of the package."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 40, size=(n, 2))
    d2 = ((xy[:, None, :] - xy[None, :, :]) ** 2).sum(-1)
    k = np.exp(-0.5 * d2 / w**2) + 0.01 * np.eye(n)
    v = np.linalg.cholesky(k) @ rng.standard_normal((n, 2))
    return xy, v


def test_the_probe_sees_length_scales_the_basis_cannot_hold():
    """Data drawn with a length scale a fifth of the basis resolution: exact's best fit beats
    hsgp's by far more than the tolerance and auto's accuracy step picks exact; drawn with twice the
    resolution, the two agree and hsgp stays. Exact is kept out of reach when it does not fit."""
    basis = dpgp.hsgp.basis_for(np.array([[0.0, 0.0], [100.0, 100.0]]), (10.0, 1.0))
    res = min(2 * h / m for h, m in zip(basis.half_widths, basis.counts))
    params = dpgp.GPParams(length_scales=(1.0, 1.0), signal_var=(1.0, 1.0), noise_var=(0.01, 0.01), mean=(0.0, 0.0))
    fast = ec.Choice("hsgp", basis.size, "hsgp initialisation", 10.0, 0.1, True)
    short = ec.resolution_gap(*_gp_draw(res / 5), params, basis)
    long = ec.resolution_gap(*_gp_draw(2 * res), params, basis)
    assert short > 2 * ec.PROBE_TOLERANCE and abs(long) < ec.PROBE_TOLERANCE / 5
    assert ec.check_accuracy(fast, short).engine == "exact"
    assert ec.check_accuracy(fast, long).engine == "hsgp"
    assert ec.check_accuracy(fast, long).resolution_gap == long
    unfit = ec.Choice("hsgp", basis.size, "hsgp initialisation", 10.0, 0.1, False)
    assert ec.check_accuracy(unfit, short).engine == "hsgp"


def test_auto_keeps_exact_where_hsgp_would_be_faster_but_inaccurate(monkeypatch):
    """hsgp predicted far faster, but the scene's fields are finer than the basis it is given:
    auto runs exact, bitwise the explicit exact fit, and records the probe's gap."""
    frames = dpgp.datasets.synthetic("intersection", n_frames=40, seed=4)
    monkeypatch.setattr(ec, "COEFFICIENTS", {"exact": (1.0, 0.0, 0.0), "hsgp": (1e-9, 0.0, 0.0, 0.0)})
    kw = dict(
        iterations=2, noise_var=0.5, length_scale_prior=(10.0, 1.0), seed=3, progress=False, posterior_draws=2,
        sampler="collapsed",
    )  # fmt: skip
    coarse = dict(kw, n_basis=(4, 4))  # a basis far too coarse for the intersection's turns
    auto = dpgp.DPGP(**coarse).fit(frames)
    assert auto.engine_choice_["resolution_gap"] > ec.PROBE_TOLERANCE
    assert auto.likelihood_ == "exact"
    _same_fit(auto, dpgp.DPGP(likelihood="exact", **kw).fit(frames))
    fine = dpgp.DPGP(**kw).fit(frames)  # the basis the sizing rule gives resolves it: hsgp stays
    assert fine.likelihood_ == "hsgp" and fine.engine_choice_["resolution_gap"] < ec.PROBE_TOLERANCE


def test_auto_over_budget_keeps_hsgp_but_warns_when_the_probe_finds_it_inaccurate(monkeypatch):
    """The same too-coarse basis, with exact's worst case over the memory budget: auto cannot run
    exact, still probes, records the gap and warns that held-out densities may suffer."""
    frames = dpgp.datasets.synthetic("intersection", n_frames=40, seed=4)
    monkeypatch.setattr(ec, "COEFFICIENTS", {"exact": (1.0, 0.0, 0.0), "hsgp": (1e-9, 0.0, 0.0, 0.0)})
    budget = ec.exact_peak_bytes(int(frames.sizes.sum())) - 1
    kw = dict(iterations=1, noise_var=0.5, length_scale_prior=(10.0, 1.0), seed=3, progress=False,
              sampler="collapsed", memory_budget=budget)  # fmt: skip
    with pytest.warns(UserWarning, match="cannot hold these data's length scales"):
        auto = dpgp.DPGP(n_basis=(4, 4), **kw).fit(frames)
    assert auto.likelihood_ == "hsgp" and not auto.engine_choice_["exact_fits"]
    assert auto.engine_choice_["resolution_gap"] > ec.PROBE_TOLERANCE


def test_partition_gap_is_the_points_weighted_gap_of_each_pattern():
    """The probe's gap on a partition: each pattern's gap on its every s-th frame (s from the
    whole data's points and the limit; a pattern shorter than s keeps its first frame), weighted by
    the pattern's points, recomputed here frame by frame."""
    frames = dpgp.datasets.synthetic("intersection", n_frames=30, seed=2)
    basis = dpgp.hsgp.basis_for(frames.xy, (10.0, 1.0))
    params = dpgp.GPParams(length_scales=(5.0, 5.0), signal_var=tuple(frames.v.var(0)), noise_var=(0.1, 0.1),
                           mean=tuple(frames.v.mean(0)))  # fmt: skip
    labels = np.array([0] * 14 + [1] * 14 + [2] * 2)  # pattern 2: fewer frames than the stride
    limit = frames.n_points // 3 + 1  # stride 3
    expected, total = 0.0, 0
    for first, last in ((0, 14), (14, 28), (28, 30)):
        rows = range(first, last, 3)
        xy = np.concatenate([frames[i].xy for i in rows])
        v = np.concatenate([frames[i].v for i in rows])
        n_k = sum(frames[i].xy.shape[0] for i in range(first, last))
        expected += n_k * ec.resolution_gap(xy, v, params, basis)
        total += n_k
    got = ec.partition_gap(labels, frames, params, basis, limit=limit)
    assert total == frames.n_points
    assert got == pytest.approx(expected / total, rel=1e-12, abs=1e-12)


def test_auto_engine_is_a_decision_about_the_data_not_the_seed(monkeypatch):
    """hsgp predicted far faster: the probe reads the initialisations of the fixed seeds
    ec.PROBE_SEEDS, whatever the fit's seed, so every seed records the same gaps and picks the same
    engine; the gap is the median of partition_gap over those initialisations (recomputed here).
    The initialisations differ (with the sized basis the per-seed gaps are not all equal), so a
    probe of the fit's own initialisation would not pass."""
    frames = dpgp.datasets.synthetic("intersection", n_frames=40, seed=4)
    monkeypatch.setattr(ec, "COEFFICIENTS", {"exact": (1.0, 0.0, 0.0), "hsgp": (1e-9, 0.0, 0.0, 0.0)})
    kw = dict(
        iterations=1, noise_var=0.5, length_scale_prior=(10.0, 1.0), progress=False, posterior_draws=2,
        sampler="collapsed",
    )  # fmt: skip
    distinct = []
    for n_basis, engine in (((4, 4), "exact"), (None, "hsgp")):
        fits = [dpgp.DPGP(seed=seed, n_basis=n_basis, **kw).fit(frames) for seed in (0, 3, 11)]
        gaps = fits[0].engine_choice_["probe_gaps"]
        assert len(gaps) == len(ec.PROBE_SEEDS)
        distinct.append(len(set(gaps)) > 1)
        for m in fits:
            assert m.likelihood_ == engine
            assert m.engine_choice_["probe_gaps"] == gaps
            assert m.engine_choice_["resolution_gap"] == float(np.median(gaps))
        hsgp = dpgp.DPGP(seed=0, n_basis=n_basis, likelihood="hsgp", **kw).fit(frames)
        again = [
            ec.partition_gap(hsgp._probe_labels(frames, s), frames, hsgp.params_, hsgp.basis_) for s in ec.PROBE_SEEDS
        ]
        np.testing.assert_allclose(again, gaps, rtol=1e-12)
        assert (np.median(again) > ec.PROBE_TOLERANCE) == (engine == "exact")
    assert distinct == [False, True]  # the coarse basis's partitions agree; the sized basis's differ


def test_subcluster_features_and_the_rule_with_the_subcluster_sampler(monkeypatch):
    """With hsgp on the sub-cluster sampler, hsgp's predicted sweep is that sampler's:
    ``[M K Σ l_f, K M³, moves (M Σ l_f / K + M³)]``; auto compares exact with it, and a fit with
    ``sampler="auto"`` probes, then runs the engine it picks on the sampler it says."""
    n, frames, m = [10, 200, 3000], [3, 4], 50
    moves = ec.subcluster_moves(len(frames))
    np.testing.assert_array_equal(
        ec.features("subcluster", n, frames, m), [7 * m * 3, 3 * m**3, moves * (7 / 3 * m + m**3)]
    )
    with pytest.raises(ValueError):
        ec.features("subcluster", n, frames)
    assert ec.subcluster_moves(1000) == 30 and ec.subcluster_moves(10_000) == 10 and ec.subcluster_moves(10**6) == 1
    fast = {"exact": (1.0, 0.0, 0.0), "hsgp": (1.0, 0.0, 0.0, 0.0), "subcluster": (1e-12, 0.0, 0.0)}
    monkeypatch.setattr(ec, "COEFFICIENTS", fast)
    assert ec.choose_upfront([10] * 30, 400, None) is not None  # the collapsed hsgp is no faster
    assert ec.choose_upfront([10] * 30, 400, None, subcluster=True) is None  # the sub-cluster one is
    assert ec.choose([300], [10] * 30, 400, None, subcluster=True).engine == "hsgp"
    frames = dpgp.datasets.synthetic("intersection", n_frames=40, seed=4)
    m = dpgp.DPGP(iterations=1, noise_var=0.5, length_scale_prior=(10.0, 1.0), progress=False).fit(frames)
    assert m.likelihood_ == "hsgp" and m.sampler_ == "subcluster"
    assert m.engine_choice_["sizes_from"] == "hsgp initialisation" and m.engine_choice_["resolution_gap"] is not None
