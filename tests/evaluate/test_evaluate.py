"""Held-out evaluation (dpgp.evaluate): every number of the table against plain numpy/scipy, the
time split, rollouts against tracks, the figure and the command line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats
from scipy.special import logsumexp

import dpgp
from dpgp.cli import main
from dpgp.evaluate import scores as ev

from gp_oracle import log_marginal_likelihood as ref_lml
from gp_oracle import log_predictive as ref_pred
from test_baselines import oracle_scores as cv_oracle

FIXTURES = Path(__file__).parents[1] / "fixtures"

WS = (6.0, 9.0)


@pytest.fixture(scope="module")
def fitted():
    frames = dpgp.datasets.synthetic("intersection", n_frames=50, seed=7)
    train, test = ev.split_in_time(frames)
    model = dpgp.DPGP(iterations=3, length_scales=WS, noise_var=0.5, seed=0, progress=False).fit(train)
    return model, train, test


def tracks_table() -> pd.DataFrame:
    """Ten vehicles on straight lines at 10 Hz for 24 s: northbound at 8 m/s, eastbound at 4 m/s."""
    rows = []
    t = np.round(np.arange(0, 24, 0.1), 6)
    for v in range(10):
        start = v * 2.0
        keep = t >= start
        tt = t[keep] - start
        if v % 2:
            x, y = np.full_like(tt, 3.0), -40 + 8.0 * tt
        else:
            x, y = -40 + 4.0 * tt, np.full_like(tt, -3.0)
        rows.append(pd.DataFrame({"track": v, "t": t[keep], "x": x, "y": y}))
    return pd.concat(rows, ignore_index=True)


def wavy_tracks_table() -> pd.DataFrame:
    """As :func:`tracks_table`, but each vehicle's speed swings along its lane, and vehicles 3 and 9
    start inside the ROI (their first frame has no previous velocity; 9 appears in the test period)."""
    rows = []
    t = np.round(np.arange(0, 24, 0.1), 6)
    for v in range(10):
        start = v * 2.0
        tt = t[t >= start] - start
        s = (-20.0 if v in (3, 9) else -40.0) + (4.0 + 4.0 * (v % 2)) * tt + 1.5 * np.sin(0.8 * tt + v)
        x, y = (np.full_like(tt, 3.0), s) if v % 2 else (s, np.full_like(tt, -3.0))
        rows.append(pd.DataFrame({"track": v, "t": t[t >= start], "x": x, "y": y}))
    return pd.concat(rows, ignore_index=True)


def test_split_in_time_keeps_the_order():
    f = dpgp.datasets.synthetic("highway", n_frames=20, seed=1)
    train, test = ev.split_in_time(f)
    assert (len(train), len(test)) == (14, 6)
    np.testing.assert_array_equal(np.r_[train.ids, test.ids], f.ids)
    with pytest.raises(dpgp.InvalidInputError, match="train_fraction"):
        ev.split_in_time(f, 1.5)
    with pytest.raises(dpgp.ShapeError):
        ev.split_in_time(f[:1])


def test_position_blind_scores_match_scipy(fitted):
    _, train, test = fitted
    mu, sd = train.v.mean(axis=0), train.v.std(axis=0)
    want = [stats.norm.logpdf(f.v, mu, sd).sum() for f in test]
    np.testing.assert_allclose(ev.position_blind_scores(train, test), want, rtol=1e-12)


def test_single_gp_scores_match_the_numpy_oracle(fitted):
    _, train, test = fitted
    p = dpgp.GPParams((7.0, 11.0), tuple(train.v.var(axis=0)), 0.3, tuple(train.v.mean(axis=0)))
    g = ev.SingleGP(p, train.xy, train.v)
    np.testing.assert_allclose(
        g.score_frames(test), [ref_pred(train.xy, train.v, f.xy, f.v, p) for f in test], rtol=1e-8
    )


def test_single_gp_takes_the_best_held_out_grid_point():
    train = dpgp.datasets.synthetic("intersection", n_frames=14, seed=3, vehicles=(4, 8))
    g = ev.SingleGP.fit(train)
    sub = ev._spread_frames(train, ev.SINGLE_GP_POINTS)
    cut = int(round(0.7 * len(sub)))
    var, mu = tuple(train.v.var(axis=0)), tuple(train.v.mean(axis=0))
    spacing = dpgp.gp.defaults.vehicle_spacing(train)
    grid = np.asarray(dpgp.gp.defaults.NOISE_GRID)  # noise variance / signal variance, per component
    scores = np.array([[
        sum(ref_pred(sub[:cut].xy, sub[:cut].v, f.xy, f.v, dpgp.GPParams((w * spacing,) * 2, var, rho * np.array(var), mu))
            for f in sub[cut:])
        for rho in grid] for w in ev.LENGTH_GRID])  # fmt: skip
    i = np.unravel_index(np.argmax(scores), scores.shape)[0]
    assert g.params.length_scales == pytest.approx((ev.LENGTH_GRID[i] * spacing,) * 2)
    rho = dpgp.gp.defaults.refine_grid(grid, scores[i])
    assert g.params.noise_var == pytest.approx(tuple(rho * np.array(var)), rel=1e-6)


def test_table_log_densities_match_the_oracles(fitted):
    model, train, test = fitted
    out = model.evaluate(test, average=False)  # the final state's density (averaging: test_posterior)
    n = test.n_points
    # dpgp: the mixture's predictive density, from the formulas (fixed length scales)
    p = dpgp.GPParams(WS, tuple(train.v.var(axis=0)), 0.5, tuple(train.v.mean(axis=0)))
    a, N = model.alpha_, len(train)
    mix = []
    for f in test:
        terms = [np.log(np.sum(model.labels_ == k) / (N + a)) + ref_pred(*_members(model, train, k), f.xy, f.v, p)
                 for k in range(model.n_patterns_)]  # fmt: skip
        terms.append(np.log(a / (N + a)) + ref_lml(f.xy, f.v, p))
        mix.append(logsumexp(terms))
    assert out.table.loc["dpgp", "log_density"] == pytest.approx(np.sum(mix) / n, rel=1e-8)
    g = ev.SingleGP.fit(train)
    want_single = sum(ref_pred(g.train_xy, g.train_v, f.xy, f.v, g.params) for f in test) / n
    assert out.table.loc["single_gp", "log_density"] == pytest.approx(want_single, rel=1e-8)
    mu, sd = train.v.mean(axis=0), train.v.std(axis=0)
    assert out.table.loc["position_blind", "log_density"] == pytest.approx(
        stats.norm.logpdf(test.v, mu, sd).sum() / n, rel=1e-12
    )
    assert np.isnan(out.table.loc["constant_velocity", "log_density"]) and out.rollouts is None
    assert (out.table["n_test_vehicles"] == n).all() and list(out.frame_scores["n_vehicles"]) == list(test.sizes)
    np.testing.assert_allclose(out.frame_scores["dpgp"], mix, rtol=1e-8)
    assert out.table.loc["dpgp", "log_density_per_frame"] == pytest.approx(np.mean(mix), rel=1e-8)
    # synthetic frames carry no previous velocities: the constant-velocity baseline is absent, with a note
    assert "constant_velocity" not in out.frame_scores.columns and out.margins["constant_velocity"] is None
    assert len(out.notes) == 1 and "test frames carry no previous velocities" in out.notes[0]
    assert out.margins["position_blind"] == pytest.approx(
        out.table.loc["dpgp", "log_density"] - out.table.loc["position_blind", "log_density"], rel=1e-12
    )
    assert "over constant_velocity not scored" in repr(out) and "note: constant_velocity not scored" in repr(out)


def test_constant_velocity_baseline_and_margins_in_the_table():
    frames = dpgp.make_frames(wavy_tracks_table(), roi=(-30.0, 30.0, -30.0, 30.0), dt=0.5)
    train, test = ev.split_in_time(frames)
    assert 0 < np.isnan(test.prev_v[:, 0]).sum() < test.n_points  # first appearances among the test vehicles
    model = dpgp.DPGP(iterations=2, noise_var=0.1, seed=0, progress=False).fit(train)
    out = model.evaluate(test)
    want = cv_oracle(train, test)  # scipy, first appearances at the position-blind density
    np.testing.assert_allclose(out.frame_scores["constant_velocity"], want, rtol=1e-12)
    t, n = out.table, test.n_points
    assert t.loc["constant_velocity", "log_density"] == pytest.approx(np.sum(want) / n, rel=1e-12)
    assert t.loc["constant_velocity", "log_density_per_frame"] == pytest.approx(np.mean(want), rel=1e-12)
    for m in ("single_gp", "position_blind", "constant_velocity"):
        per_frame = out.frame_scores["dpgp"] - out.frame_scores[m]
        assert t.loc[m, "dpgp_margin"] == pytest.approx(per_frame.sum() / n, rel=1e-9)
    assert np.isnan(t.loc["dpgp", "dpgp_margin"]) and out.notes == ()
    assert out.margins == pytest.approx(
        {m: t.loc["dpgp", "log_density"] - t.loc[m, "log_density"] for m in ("position_blind", "constant_velocity")}
    )
    assert "over constant_velocity" in repr(out) and "note:" not in repr(out)
    assert len(out.plot().axes[0].patches) == 4  # a bar per method
    # training frames without previous velocities (a model file written before they were kept)
    model.frames_ = dpgp.Frames(train.ids, train.offsets, train.xy, train.v)
    out = model.evaluate(test)
    assert np.isnan(out.table.loc["constant_velocity", "log_density"]) and "training frames carry" in out.notes[0]


def _members(model, train, k):
    m = train[np.flatnonzero(model.labels_ == k)]
    return m.xy, m.v


def test_rollout_errors_match_a_numpy_computation():
    tracks = tracks_table()
    roi = (-30.0, 30.0, -30.0, 30.0)
    frames = dpgp.make_frames(tracks, roi=roi, dt=0.5)
    train, test = ev.split_in_time(frames)
    model = dpgp.DPGP(iterations=2, noise_var=0.1, length_scale_prior=(10.0, 1.0), seed=0, progress=False).fit(train)
    out = model.evaluate(test, tracks=tracks, horizons=(0.5, 2))
    r = out.rollouts.set_index("horizon")
    # the oracle: each vehicle found by its position in the analytic tracks
    err = {"dpgp": {0.5: [], 2.0: []}, "constant_velocity": {0.5: [], 2.0: []}}
    fde = {"dpgp": {0.5: [], 2.0: []}, "constant_velocity": {0.5: [], 2.0: []}}
    patterns = model.predict(test)
    for i, f in enumerate(test):
        t0 = float(test.ids[i])
        sim = model.simulate(f, pattern=int(patterns[i]), steps=4, dt=0.5, low_data_threshold=None)
        for j, (x, y) in enumerate(f.xy):
            v = 0 if y == -3.0 and x != 3.0 else 1  # eastbound tracks are even
            cand = tracks[(np.isclose(tracks.t, t0)) & np.isclose(tracks.x, x) & np.isclose(tracks.y, y)]
            track = int(cand.track.iloc[0])
            mine = tracks[tracks.track == track]
            for h in (0.5, 2.0):
                s = int(h / 0.5)
                truth = np.array([mine[np.isclose(mine.t, t0 + 0.5 * q)][["x", "y"]].to_numpy()[0] for q in range(1, s + 1)
                                  if np.isclose(mine.t, t0 + 0.5 * q).any()])  # fmt: skip
                if len(truth) < s or not (roi[0] <= truth[-1][0] <= roi[1] and roi[2] <= truth[-1][1] <= roi[3]):
                    continue
                cv = f.xy[j] + np.arange(1, s + 1)[:, None] * 0.5 * f.v[j]
                for m, pred in (("dpgp", sim.positions[1 : s + 1, j]), ("constant_velocity", cv)):
                    d = np.linalg.norm(pred - truth, axis=1)
                    err[m][h].append(d.mean())
                    fde[m][h].append(d[-1])
            del v
    for h in (0.5, 2.0):
        assert r.loc[h, "n_vehicles"] == len(err["dpgp"][h]) > 0
        for m in ("dpgp", "constant_velocity"):
            assert r.loc[h, f"{m}_ade"] == pytest.approx(np.mean(err[m][h]), abs=1e-9)
            assert r.loc[h, f"{m}_fde"] == pytest.approx(np.mean(fde[m][h]), abs=1e-9)
            assert out.table.loc[m, f"fde_{h:g}s"] == pytest.approx(np.mean(fde[m][h]), abs=1e-9)
    assert r.loc[2.0, "constant_velocity_fde"] == pytest.approx(0.0, abs=1e-9)  # straight lines at constant speed
    # ... so the constant-velocity density is degenerate: not scored, with the reason, not an error
    assert out.margins["constant_velocity"] is None and "no spread" in out.notes[0]
    fig = out.plot()
    assert len(fig.axes) == 2


def test_the_constant_velocity_baseline_stops_at_the_roi_as_the_core_rollouts_do():
    """The rollouts' constant-velocity baseline is the core's relaxed rollout with τ = ∞ (the
    residual never relaxes), bit for bit: vehicles that leave the ROI stand at their first
    position outside it, one that starts outside never moves."""
    from dpgp.evaluate.scores import constant_velocity_rollout
    from dpgp.generate import motion
    from dpgp.generate.rollout import motion_rollouts

    model = dpgp.DPGP.load(FIXTURES / "field_model.npz")
    fit = model._fitted()
    xy = np.array([[0.0, 0.0], [8.0, 1.0], [-3.0, 2.0], [12.0, 0.0]])
    v = np.array([[1.5, 0.2], [3.0, -1.0], [-0.5, 4.0], [1.0, 1.0]])
    roi = (-5.0, 10.0, -4.0, 6.0)  # the last vehicle starts outside it
    k = fit.n_patterns
    still = motion.MotionModel("vehicles", np.full(k, np.inf), np.zeros((k, 2)), np.zeros(k, np.int64), np.ones(k), 1.0)
    core = motion_rollouts(fit, [0], [xy], [v], steps=12, dt=0.5, seeds=None, roi=roi, low_data_threshold=None,
                           dynamics="relaxed", motion=still)[0]  # fmt: skip
    got = constant_velocity_rollout(xy, v, 12, 0.5, roi)
    np.testing.assert_array_equal(got, core.positions)
    assert not np.array_equal(got[-1, :3], xy[:3] + 12 * 0.5 * v[:3])  # they did leave and stand
    np.testing.assert_array_equal(got[:, 3], np.broadcast_to(xy[3], (13, 2)))


def test_bad_input_raises_typed_errors(fitted):
    model, _, test = fitted
    with pytest.raises(dpgp.InvalidInputError, match="horizons"):
        model.evaluate(test, horizons=(0, 1))
    with pytest.raises(dpgp.InvalidInputError, match="summary"):
        model.evaluate(test, tracks=tracks_table())
    with pytest.raises(dpgp.NotFittedError):
        dpgp.DPGP().evaluate(test)


def test_cli_evaluate_writes_the_table_and_the_figure(tmp_path, capsys):
    data = tmp_path / "tracks.csv"
    tracks = wavy_tracks_table()
    tracks.to_csv(data, index=False)
    model = tmp_path / "m.npz"
    frames = dpgp.make_frames(tracks, roi=(-30.0, 30.0, -30.0, 30.0), dt=0.5)
    fitted = dpgp.DPGP(iterations=2, noise_var=0.1, seed=0, progress=False).fit(ev.split_in_time(frames)[0])
    fitted.save(model)
    csv, png = tmp_path / "table.csv", tmp_path / "eval.png"
    assert main(["evaluate", str(model), str(data), "-o", str(csv), "--plot", str(png), "--horizons", "1", "2"]) == 0
    table = pd.read_csv(csv, index_col="method")
    assert {"log_density", "dpgp_margin", "ade_1s", "fde_2s"} <= set(table.columns) and png.stat().st_size > 0
    # the model file keeps the training frames' previous velocities: the baseline is scored
    test = ev.split_in_time(frames)[1]
    want = np.sum(cv_oracle(fitted.frames_, test)) / test.n_points
    assert table.loc["constant_velocity", "log_density"] == pytest.approx(want, rel=1e-12)
    printed = capsys.readouterr().out
    margin = table.loc["constant_velocity", "dpgp_margin"]
    assert f"over constant_velocity {margin:+.3f}" in printed and "note:" not in printed
    # recorded windows' criticality beside generated scenes'
    assert "criticality" in printed and "recorded" in printed and "generated" in printed
