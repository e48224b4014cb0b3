"""Scenario generation: vehicle counts follow φ and patterns their weights (χ² tests with a
fixed seed), positions come from the pattern's own data, velocities from its GP; CSV and SUMO
FCD exports, the latter read back by our own SUMO reader."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import stats

import dpgp
import dpgp.generate.motion
from dpgp.generate import scenarios as sc


@pytest.fixture(scope="module")
def model() -> dpgp.DPGP:
    # vehicles per frame uniform on 3..9, so φ is far from any one count
    frames = dpgp.datasets.synthetic("intersection", n_frames=50, seed=5, vehicles=(3, 9))
    # the paper's σ_n² and prior and full proposals: every pattern then holds enough positions
    # for its own ψ (after two informed sweeps, 11 of 15 patterns hold one to three frames)
    return dpgp.DPGP(
        iterations=2, seed=0, progress=False, noise_var=1.0, length_scale_prior=(10.0, 1.0), proposal="full"
    ).fit(frames)


def _pooled(observed: np.ndarray, expected: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop impossible cells (none may be observed) and merge those with expected count < 5
    into one (the χ² approximation needs it)."""
    assert observed[expected == 0].sum() == 0, "a count of probability 0 was drawn"
    observed, expected = observed[expected > 0], expected[expected > 0]
    small = expected < 5
    if small.any():
        observed = np.r_[observed[~small], observed[small].sum()]
        expected = np.r_[expected[~small], expected[small].sum()]
    return observed, expected


def test_vehicle_counts_follow_phi(model):
    """The paper's generator (dynamics="field") draws the count from φ; the interactive one
    draws a frame of the pattern (whose sizes pool to φ) and thins it (next test)."""
    n = 3000
    # steps=0, mean velocities, no flags: only the draws under test cost anything
    scen = model.sample_scenarios(n, steps=0, seed=2024, stochastic=False, low_data_threshold=None, dynamics="field")
    phi = sc.distributions(model).count_pmf()
    np.testing.assert_allclose(phi, np.bincount(model.frames_.sizes, minlength=len(phi)) / len(model.frames_))
    observed = np.bincount(scen.counts, minlength=len(phi)).astype(float)
    assert len(observed) == len(phi), "a count φ gives probability 0 was drawn"
    assert np.array_equal(scen.counts, [s.n_vehicles for s in scen])
    o, e = _pooled(observed, n * phi)
    assert stats.chisquare(o, e).pvalue > 0.01
    # the test has power: the same counts are clearly not uniform over the support of φ
    support = phi > 0
    uniform = np.where(support, n / support.sum(), 0.0)
    o2, e2 = _pooled(observed, uniform)
    assert stats.chisquare(o2, e2).pvalue < 1e-6


def _thinned(xy: np.ndarray, spacing: float) -> np.ndarray:
    kept: list[np.ndarray] = []
    for p in xy:
        if all(np.hypot(*(p - q)) >= spacing for q in kept):
            kept.append(p)
    return np.array(kept).reshape(-1, 2)


def test_interactive_scenes_start_from_a_thinned_recorded_configuration(model):
    """Each generated scene starts at the positions of one of its pattern's training frames, less
    the vehicles closer than the pattern's spacing to one kept before them (numpy oracle)."""
    fit = model._fitted()
    spacing = dpgp.generate.motion.motion_model(fit).spacing
    scen = model.sample_scenarios(60, steps=0, seed=11, stochastic=False)
    for s, k in zip(scen, scen.patterns):
        own = [model.frames_[int(f)].xy for f in np.flatnonzero(model.labels_ == k)]
        match = [xy for xy in own if np.array_equal(_thinned(xy, spacing[k]), s.positions[0])]
        assert match, f"scene of pattern {k} is no thinned frame of it"
    # the counts are the frames' sizes less what thinning removed: φ's mean, a little less
    phi = sc.distributions(model).count_pmf()
    mean_phi = float((np.arange(len(phi)) * phi).sum())
    assert 0.8 * mean_phi < scen.counts.mean() <= mean_phi + 1.0
    assert np.array_equal(scen.counts, [s.n_vehicles for s in scen])


def test_patterns_follow_their_weights(model):
    n = 3000
    scen = model.sample_scenarios(n, steps=0, seed=7, stochastic=False, low_data_threshold=None)
    observed = np.bincount(scen.patterns, minlength=model.n_patterns_)
    assert stats.chisquare(observed, n * model.weights_).pvalue > 0.01
    fixed = model.sample_scenarios(20, steps=0, pattern=1, seed=7, stochastic=False)
    assert (fixed.patterns == 1).all() and all(s.pattern == 1 for s in fixed)


def test_positions_come_from_the_patterns_own_data(model):
    psi = sc.distributions(model)
    for k in range(model.n_patterns_):
        own = sc.pattern_positions(model, k, psi)
        assert own is not psi and own.roi == psi.roi and own.bins == psi.bins
        scen = model.sample_scenarios(40, steps=0, pattern=k, seed=k, stochastic=False)
        start = np.concatenate([s.positions[0] for s in scen])
        assert np.isfinite(own.log_position_density(start)).all(), "a vehicle in a bin without data of the pattern"
        # ... and the pattern's own distribution is narrower than ψ: some ψ bins are empty for it
        assert (own.position_hist == 0).sum() > (psi.position_hist == 0).sum()


def test_fallback_to_psi_for_patterns_with_little_data(model, monkeypatch):
    psi = sc.distributions(model)
    monkeypatch.setattr(sc, "MIN_OWN_POSITIONS", 10**9)
    assert sc.pattern_positions(model, 0, psi) is psi


@pytest.mark.parametrize("dynamics", ["field", "interactive"])
def test_velocities_are_drawn_from_the_pattern_gp(model, dynamics, monkeypatch):
    if dynamics == "interactive":
        # without interaction (rule 0, free): a follower would start no faster than its gap allows
        records = sc.motion_records

        def free(*args, **kwargs):
            out = np.array(records(*args, **kwargs))
            out[:, 3] = 0.0
            return out

        monkeypatch.setattr(sc, "motion_records", free)
    mean = model.sample_scenarios(30, steps=0, pattern=0, seed=1, stochastic=False, dynamics=dynamics)
    drawn = model.sample_scenarios(
        30, steps=0, pattern=0, seed=1, dynamics=dynamics
    )  # same positions, velocities drawn
    # interactive: the latent draw plus the residual's stationary spread (dpgp.motion)
    sigma2 = 0.0 if dynamics == "field" else dpgp.generate.motion.motion_model(model._fitted()).sigma[0] ** 2
    z = []
    for a, b in zip(mean, drawn):
        np.testing.assert_array_equal(a.positions, b.positions)
        m, var = model.velocity_field(0, a.positions[0])
        np.testing.assert_allclose(a.velocities[0], m, rtol=1e-9, atol=1e-9)
        z.append((b.velocities[0] - m) / np.sqrt(var + sigma2))
    z = np.concatenate(z).ravel()
    # standardised draws: mean 0, variance 1 (marginally; they are correlated within a scenario)
    assert abs(z.mean()) < 0.25 and 0.6 < z.var() < 1.5


def test_generation_is_seeded(model):
    a = model.sample_scenarios(6, steps=5, seed=3).to_pandas()
    b = model.sample_scenarios(6, steps=5, seed=3).to_pandas()
    c = model.sample_scenarios(6, steps=5, seed=4).to_pandas()
    pd.testing.assert_frame_equal(a, b)
    assert not a.equals(c)


def test_csv_export(model, tmp_path):
    scen = model.sample_scenarios(4, steps=8, seed=9)
    df = scen.to_pandas()
    assert list(df.columns) == ["scenario", "vehicle", "t", "x", "y", "vx", "vy"]
    inside = sum(int(s.in_roi.sum()) for s in scen)
    assert len(df) == inside, "rows are the vehicle-times inside the ROI"
    x0, x1, y0, y1 = scen[0].roi
    assert df["x"].between(x0, x1).all() and df["y"].between(y0, y1).all()
    scen.save(tmp_path / "s.csv")
    back = pd.read_csv(tmp_path / "s.csv")
    pd.testing.assert_frame_equal(back, df, check_exact=True)


def test_sumo_fcd_round_trip(model, tmp_path):
    scen = model.sample_scenarios(3, steps=6, seed=10)
    path = tmp_path / "scenarios.xml"
    scen.save(path)  # SUMO from the extension
    assert path.read_text().lstrip().startswith("<?xml") and "<fcd-export" in path.read_text()
    tracks = dpgp.read_tracks(path)
    assert tracks.attrs["dpgp"]["format"] == "sumo"
    ids = tracks["id"].str.extract(r"s(\d+)_v(\d+)").astype(int)
    got = pd.DataFrame({"scenario": ids[0], "vehicle": ids[1], "t": tracks["t"], "x": tracks["x"], "y": tracks["y"],
                        "vx": tracks["vx"], "vy": tracks["vy"]})  # fmt: skip
    got["t"] -= got["scenario"] * (6 + 1) * scen.dt  # scenarios follow one another in time
    want = scen.to_pandas()
    got = got.sort_values(["scenario", "t", "vehicle"]).reset_index(drop=True)
    want = want.sort_values(["scenario", "t", "vehicle"]).reset_index(drop=True)
    np.testing.assert_array_equal(got[["scenario", "vehicle"]].to_numpy(), want[["scenario", "vehicle"]].to_numpy())
    np.testing.assert_allclose(
        got[["t", "x", "y", "vx", "vy"]].to_numpy(), want[["t", "x", "y", "vx", "vy"]].to_numpy(), atol=2e-5
    )
    # gzip too
    scen.to_sumo(tmp_path / "s.xml.gz")
    assert len(dpgp.read_tracks(tmp_path / "s.xml.gz")) == len(tracks)


def test_bad_arguments(model):
    for kwargs in (dict(n=-1), dict(n=2.5), dict(n=2, pattern=99), dict(n=2, seed=-1), dict(n=2, method="x")):
        with pytest.raises(dpgp.InvalidInputError):
            model.sample_scenarios(**kwargs)
    with pytest.raises(dpgp.InvalidInputError, match="format"):
        model.sample_scenarios(1, steps=1, seed=0).save("x.out", format="parquet")
    assert len(model.sample_scenarios(0, seed=0)) == 0
