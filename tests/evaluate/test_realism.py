"""The WOSAC-style realism score (dpgp.realism): the whole score against an independent oracle
written here with explicit loops, the features against hand-computed values, the collision
rule and its units, the ratio, the recorded windows, the position-blind generator's seeding,
typed errors, and the ways in (dpgp.evaluate.realism, model.evaluate, dpgp evaluate)."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

import dpgp
from dpgp import evaluate as ev
from dpgp.cli import main
from dpgp.evaluate import realism_checks as rl

from test_evaluate import tracks_table as straight_tracks

WEIGHTS = {"speed": 0.05, "acceleration": 0.05, "turn_rate": 0.05, "angular_acceleration": 0.05,
           "nearest_distance": 0.10, "collision": 0.25, "count": 0.10, "position": 0.10}  # fmt: skip


# --- the oracle: the definition, written out with loops --------------------------------
def oracle_features(table: pd.DataFrame, dt: float, threshold: float, min_speed: float) -> dict[str, list]:
    pos = {}  # (scenario, vehicle) -> {time step: (x, y)}
    for s, v, t, x, y in table[["scenario", "vehicle", "t", "x", "y"]].itertuples(index=False):
        pos.setdefault((s, v), {})[int(round(t / dt))] = (x, y)
    out = {k: [] for k in WEIGHTS}
    for track in pos.values():
        speed, heading, turn = {}, {}, {}
        for k, (x, y) in track.items():
            if k + 1 in track:
                dx, dy = track[k + 1][0] - x, track[k + 1][1] - y
                speed[k] = math.hypot(dx, dy) / dt
                if speed[k] >= min_speed:
                    heading[k] = math.atan2(dy, dx)
        for k in speed:
            out["speed"].append(speed[k])
            if k + 1 in speed:
                out["acceleration"].append((speed[k + 1] - speed[k]) / dt)
        for k in heading:
            if k + 1 in heading:
                d = heading[k + 1] - heading[k]
                while d > math.pi:
                    d -= 2 * math.pi
                while d <= -math.pi:
                    d += 2 * math.pi
                turn[k] = d / dt
                out["turn_rate"].append(turn[k])
        for k in turn:
            if k + 1 in turn:
                out["angular_acceleration"].append((turn[k + 1] - turn[k]) / dt)
    groups = {}
    for s, t, x, y in table[["scenario", "t", "x", "y"]].itertuples(index=False):
        groups.setdefault((s, int(round(t / dt))), []).append((x, y))
    for members in groups.values():
        out["count"].append(len(members))
        for i, (x, y) in enumerate(members):
            near = min((math.hypot(x - u, y - w) for j, (u, w) in enumerate(members) if j != i), default=math.inf)
            if near < math.inf:
                out["nearest_distance"].append(near)
            out["collision"].append(near < threshold)
            out["position"].append((x, y))
    return out


def oracle_quantile(values: list[float], q: float) -> float:
    v = sorted(values)
    at = q * (len(v) - 1)
    lo = int(math.floor(at))
    hi = min(lo + 1, len(v) - 1)
    return v[lo] + (at - lo) * (v[hi] - v[lo])


def oracle_bin(edges: list[float], value: float) -> int:
    """The bin of ``value``; beyond the range, the end bin."""
    n = len(edges) - 1
    for i in range(n):
        if value < edges[i + 1]:
            return i
    return n - 1


def oracle_histogram_score(gen: list, rec: list, edges: list[float], pseudo: float = 0.1) -> float:
    counts = [0] * (len(edges) - 1)
    for g in gen:
        counts[oracle_bin(edges, g)] += 1
    total = len(gen) + pseudo * len(counts)
    logs = [math.log((counts[oracle_bin(edges, r)] + pseudo) / total) for r in rec]
    return math.exp(sum(logs) / len(logs))


def oracle_scores(gen: dict, rec: dict, train: dict, n_bins: int = 20) -> dict[str, float]:
    def linspace(lo, hi):
        if not hi > lo:
            lo, hi = lo - 0.5, hi + 0.5
        return [lo + (hi - lo) * i / n_bins for i in range(n_bins + 1)]

    out = {}
    for name in ("speed", "acceleration", "turn_rate", "angular_acceleration", "nearest_distance"):
        edges = linspace(oracle_quantile(train[name], 0.005), oracle_quantile(train[name], 0.995))
        out[name] = oracle_histogram_score(gen[name], rec[name], edges)
    lo, hi = min(train["count"]), max(train["count"])
    out["count"] = oracle_histogram_score(gen["count"], rec["count"], [lo - 0.5 + i for i in range(hi - lo + 2)])
    ex = linspace(min(p[0] for p in train["position"]), max(p[0] for p in train["position"]))
    ey = linspace(min(p[1] for p in train["position"]), max(p[1] for p in train["position"]))
    cells = [(i, j) for i in range(n_bins) for j in range(n_bins)]
    counts = {c: 0 for c in cells}
    for x, y in gen["position"]:
        counts[(oracle_bin(ex, x), oracle_bin(ey, y))] += 1
    total = len(gen["position"]) + 0.1 * len(cells)
    logs = [math.log((counts[(oracle_bin(ex, x), oracle_bin(ey, y))] + 0.1) / total) for x, y in rec["position"]]
    out["position"] = math.exp(sum(logs) / len(logs))
    p = (sum(gen["collision"]) + 0.1) / (len(gen["collision"]) + 0.2)
    logs = [math.log(p if c else 1 - p) for c in rec["collision"]]
    out["collision"] = math.exp(sum(logs) / len(logs))
    out["meta"] = sum(WEIGHTS[k] * out[k] for k in WEIGHTS) / sum(WEIGHTS.values())
    return out


def random_scenarios(seed: int, n: int = 12, steps: int = 8, dt: float = 0.5, spread: float = 1.0) -> pd.DataFrame:
    """Random walks that turn, stop, crowd together and leave (a vehicle's rows end early)."""
    rng = np.random.default_rng(seed)
    rows = []
    for s in range(n):
        for v in range(int(rng.integers(1, 6))):
            p = rng.uniform(0, 20, 2)
            vel = rng.normal(0, 3, 2)
            last = int(rng.integers(0, steps + 1))
            for k in range(last + 1):
                rows.append((s, v, k * dt, p[0], p[1]))
                vel = vel + rng.normal(0, spread, 2) * (rng.random() < 0.8)
                if rng.random() < 0.1:
                    vel = np.zeros(2)  # a stop: no heading
                p = p + dt * vel
    return pd.DataFrame(rows, columns=["scenario", "vehicle", "t", "x", "y"])


@pytest.mark.parametrize("agent", ["vehicle", "pedestrian"])
def test_the_score_matches_an_independent_oracle(agent):
    gen, rec, train = random_scenarios(1, spread=2.0), random_scenarios(2), random_scenarios(3)
    out = rl.realism(gen, rec, {"recorded": train}, agent=agent)
    thr = {"vehicle": 2.0, "pedestrian": 0.3}[agent]
    f = {name: oracle_features(t, 0.5, thr, 0.5) for name, t in (("gen", gen), ("rec", rec), ("train", train))}
    want = oracle_scores(f["gen"], f["rec"], f["train"])
    got = out.scores["generated"]
    for k, v in want.items():
        assert got[k] == pytest.approx(v, rel=1e-9), k
    # the training reference is scored the same way, on the same bins
    want_ref = oracle_scores(f["train"], f["rec"], f["train"])
    for k, v in want_ref.items():
        assert out.scores.loc[k, "recorded"] == pytest.approx(v, rel=1e-9), k
    assert out.collision_rates["generated"] == pytest.approx(np.mean(f["gen"]["collision"]))
    assert 0 < out.scores.loc["collision", "generated"] < 1


def test_the_bins_come_from_the_training_table_not_the_scored_ones():
    gen, rec, train = random_scenarios(4), random_scenarios(5), random_scenarios(6)
    a = rl.realism(gen, rec, train=train)
    b = rl.realism(gen, rec, {"recorded": train})
    assert a.scores.loc["meta", "generated"] == pytest.approx(b.scores.loc["meta", "generated"], rel=1e-12)
    c = rl.realism(gen, rec)  # no training table: bins from the recorded one
    f = {n: oracle_features(t, 0.5, 2.0, 0.5) for n, t in (("gen", gen), ("rec", rec))}
    assert c.scores.loc["meta", "generated"] == pytest.approx(
        oracle_scores(f["gen"], f["rec"], f["rec"])["meta"], rel=1e-9
    )


# --- features by hand --------------------------------------------------------------------------
def table(rows, columns=("scenario", "vehicle", "t", "x", "y")) -> pd.DataFrame:
    return pd.DataFrame(rows, columns=list(columns))


def test_kinematics_by_hand():
    # vehicle 0 speeds up along x: steps 1, 2, 3 m in 1 s; vehicle 1 turns left by 90° twice
    # (far from vehicle 0); the rows are given out of order
    rows = [(0, 0, 3.0, 6, 0), (0, 0, 0.0, 0, 0), (0, 0, 1.0, 1, 0), (0, 0, 2.0, 3, 0),
            (0, 1, 0.0, 100, 100), (0, 1, 1.0, 102, 100), (0, 1, 2.0, 102, 102), (0, 1, 3.0, 100, 102)]  # fmt: skip
    f = rl.extract_features(table(rows))
    assert f.dt == 1.0
    np.testing.assert_allclose(sorted(f.values["speed"]), [1, 2, 2, 2, 2, 3])
    np.testing.assert_allclose(sorted(f.values["acceleration"]), [0, 0, 1, 1])
    np.testing.assert_allclose(sorted(f.values["turn_rate"]), [0, 0, np.pi / 2, np.pi / 2])
    np.testing.assert_allclose(sorted(f.values["angular_acceleration"]), [0, 0])
    np.testing.assert_allclose(f.values["count"], [2, 2, 2, 2])
    assert not f.values["collision"].any()
    assert f.values["position"].shape == (8, 2)


def test_turn_rate_wraps_and_standing_objects_have_no_heading():
    a = np.radians(170.0)
    b = np.radians(-170.0)
    p1 = (np.cos(a), np.sin(a))
    p2 = (p1[0] + np.cos(b), p1[1] + np.sin(b))
    rows = [(0, 0, 0.0, 0, 0), (0, 0, 0.5, *p1), (0, 0, 1.0, *p2),
            (1, 0, 0.0, 5, 5), (1, 0, 0.5, 5, 5), (1, 0, 1.0, 5.1, 5)]  # fmt: skip
    f = rl.extract_features(table(rows))
    np.testing.assert_allclose(f.values["turn_rate"], [np.radians(20.0) / 0.5])  # not -340°
    np.testing.assert_allclose(sorted(f.values["speed"]), [0.0, 0.2, 2.0, 2.0])
    np.testing.assert_allclose(sorted(f.values["acceleration"]), [0.0, 0.4])


def test_a_gap_in_time_breaks_the_kinematics():
    rows = [(0, 0, 0.0, 0, 0), (0, 0, 0.5, 1, 0), (0, 0, 1.5, 5, 0), (0, 0, 2.0, 6, 0)]
    f = rl.extract_features(table(rows))
    np.testing.assert_allclose(f.values["speed"], [2.0, 2.0])  # nothing across the missing 1.0 s
    assert len(f.values["acceleration"]) == 0
    g = rl.extract_features(table(rows), dt=0.25)  # a stated dt that no step matches
    assert len(g.values["speed"]) == 0


def test_nearest_distance_collisions_and_their_units():
    # scenario 0, t 0: three objects at 0, 1.5 and 10 along x; t 1: one alone; scenario 1: two at 0.25
    rows = [(0, 0, 0.0, 0, 0), (0, 1, 0.0, 1.5, 0), (0, 2, 0.0, 10, 0), (0, 0, 1.0, 0, 0),
            (1, 0, 0.0, 3, 3), (1, 1, 0.0, 3, 3.25)]  # fmt: skip
    f = rl.extract_features(table(rows))  # vehicles, metres: below 2 m collides
    np.testing.assert_allclose(sorted(f.values["nearest_distance"]), [0.25, 0.25, 1.5, 1.5, 8.5])
    assert f.collision_distance == 2.0 and f.values["collision"].sum() == 4 and len(f.values["collision"]) == 6
    np.testing.assert_allclose(sorted(f.values["count"]), [1, 2, 3])
    p = rl.extract_features(table(rows), agent="pedestrian")  # 0.3 m
    assert p.values["collision"].sum() == 2 and p.collision_rate == pytest.approx(2 / 6)
    # in feet: 2 m is 6.56 ft (1.5 and 0.25 ft collide), 0.3 m is 0.98 ft (only 0.25 ft does)
    assert rl.extract_features(table(rows), units="ft").values["collision"].sum() == 4
    assert rl.extract_features(table(rows), agent="pedestrian", units="ft").values["collision"].sum() == 2
    assert rl.collision_threshold("vehicle", "ft") == pytest.approx(2.0 / 0.3048)
    assert rl.collision_threshold("pedestrian", "ft") == pytest.approx(0.3 / 0.3048)
    q = rl.extract_features(table(rows), collision_distance=0.2)  # a stated distance: nothing that close
    assert not q.values["collision"].any()
    assert rl.extract_features(table(rows), collision_distance=1.6).values["collision"].sum() == 4


def test_a_score_by_hand():
    # generated speeds 1, 1, 3 on the bins [0, 2), [2, 4]: P(bin 0) = (2 + 0.1) / 3.2,
    # P(bin 1) = 1.1 / 3.2; recorded speeds 1 and 3
    def moving(speeds):
        return table([(s, 0, t, x, 0) for s, v in enumerate(speeds) for t, x in ((0.0, 0.0), (1.0, v))])

    gen, rec = moving([1, 1, 3]), moving([1, 3])
    bins = rl.Bins({"speed": np.array([0.0, 2.0, 4.0])})
    s = rl.feature_score("speed", rl.extract_features(gen), rl.extract_features(rec), bins)
    assert s == pytest.approx(math.sqrt(2.1 / 3.2 * 1.1 / 3.2))
    assert rl.feature_score("speed", rl.extract_features(gen), rl.extract_features(moving([9])), bins) == pytest.approx(
        1.1 / 3.2
    )
    edges = rl.Bins.from_features(rl.extract_features(moving(np.linspace(0, 4, 201))), bins=4).edges["speed"]
    np.testing.assert_allclose(edges, np.linspace(*np.quantile(np.linspace(0, 4, 201), [0.005, 0.995]), 5))
    # collision: 1 of 4 generated steps, recorded 0 of 2: (1 - 1.1 / 4.2)
    g = rl.extract_features(table([(0, 0, 0.0, 0, 0), (0, 1, 0.0, 1, 0), (1, 0, 0.0, 0, 0), (1, 1, 0.0, 9, 0)]))
    g = rl.Features({**g.values, "collision": np.array([True, False, False, False])}, g.dt, g.collision_distance)
    r = rl.extract_features(table([(0, 0, 0.0, 0, 0), (0, 1, 0.0, 9, 0)]))
    assert rl.feature_score("collision", g, r, bins) == pytest.approx(1 - 1.1 / 4.2)
    assert rl.meta_score({"speed": 0.5, "collision": 0.9, "count": float("nan")}) == pytest.approx(
        (0.05 * 0.5 + 0.25 * 0.9) / 0.30
    )


def test_the_ratio():
    rec, train = random_scenarios(7), random_scenarios(8)
    blind = random_scenarios(9, spread=6.0)
    same = rl.realism(train, rec, {"recorded": train, "blind": blind})
    assert same.ratio == pytest.approx(1.0)
    none = rl.realism(blind, rec, {"recorded": train, "blind": blind})
    assert none.ratio == pytest.approx(0.0, abs=1e-12)
    mid = rl.realism(random_scenarios(10), rec, {"recorded": train, "blind": blind})
    m = mid.scores.loc["meta"]
    assert mid.ratio == pytest.approx((m["generated"] - m["blind"]) / (m["recorded"] - m["blind"]))
    assert mid.table.loc["realism_ratio", "generated"] == mid.ratio
    assert np.isnan(rl.realism(train, rec, {"recorded": train}).ratio)  # no blind reference: no ratio
    t = mid.table
    assert list(t.columns) == ["weight", "generated", "recorded", "blind", "test"]
    assert t.loc["meta", "weight"] == pytest.approx(0.75)
    assert t.loc["collision_rate", "test"] == pytest.approx(mid.collision_rates["test"])
    fig = mid.plot()
    assert len(fig.axes) == 9
    assert len(mid.plot("blind").axes) == 9


# --- the references ----------------------------------------------------------------------------
def train_frames() -> dpgp.Frames:
    return dpgp.datasets.synthetic("intersection", n_frames=30, seed=3)


def test_the_position_blind_generator_is_seeded_and_blind():
    train = train_frames()
    roi = train.bounds()
    a = rl.position_blind_scenarios(train, 40, 6, 0.5, roi=roi, seed=11)
    b = rl.position_blind_scenarios(train, 40, 6, 0.5, roi=roi, seed=11)
    c = rl.position_blind_scenarios(train, 40, 6, 0.5, roi=roi, seed=12)
    pd.testing.assert_frame_equal(a, b)
    assert not a.equals(c)
    first = a[a.t == 0]
    # counts are training counts; start positions are training positions
    assert set(first.groupby("scenario").size()) <= set(train.sizes.tolist())
    assert first.scenario.nunique() == 40
    known = {tuple(p) for p in train.xy}
    assert all((x, y) in known for x, y in first[["x", "y"]].itertuples(index=False))
    # constant velocity, and nothing outside the ROI
    for (_, _), g in a.groupby(["scenario", "vehicle"]):
        np.testing.assert_allclose(g.x.to_numpy(), g.x.iloc[0] + g.t.to_numpy() * g.vx.iloc[0])
        np.testing.assert_allclose(g.y.to_numpy(), g.y.iloc[0] + g.t.to_numpy() * g.vy.iloc[0])
        np.testing.assert_allclose(np.diff(g.t.to_numpy()), 0.5)  # a vehicle that left is gone
    assert a.x.between(roi[0], roi[1]).all() and a.y.between(roi[2], roi[3]).all()
    big = rl.position_blind_scenarios(train, 3000, 0, 0.5, seed=0)
    np.testing.assert_allclose(big[["vx", "vy"]].mean(), train.v.mean(axis=0), atol=0.15 * train.v.std(axis=0).max())


def tracks_table() -> pd.DataFrame:
    """Vehicle 0 eastbound at 2 m/s from x = 0; vehicle 1 northbound at 1 m/s from y = -2 at
    x = 5, from t = 1 s; vehicle 2 standing at (8, 8) from t = 0 to 2 s; all sampled at 10 Hz."""
    rows = []
    for k in range(0, 61):
        t = round(0.1 * k, 6)
        rows.append((0, t, 2.0 * t, 0.0))
        if t >= 1.0:
            rows.append((1, t, 5.0, -2.0 + (t - 1.0)))
        if t <= 2.0:
            rows.append((2, t, 8.0, 8.0))
    return pd.DataFrame(rows, columns=["track", "t", "x", "y"])


def test_recorded_windows_follow_the_frames_objects():
    tracks = tracks_table()
    roi = (-1.0, 9.0, -1.0, 9.0)
    frames = dpgp.make_frames(tracks, roi=roi, dt=0.5)
    w = rl.recorded_windows(tracks, frames, 4)
    # frame at t = 1.0 s (index 2): vehicles 0 (x = 2) and 2; vehicle 1 is at y = -2, outside
    s = w[w.scenario == 2]
    assert sorted(s[s.t == 0].x.round(9)) == [2.0, 8.0]
    v0 = s[s.x.round(9).isin([2.0, 3.0, 4.0, 5.0, 6.0])].sort_values("t")
    np.testing.assert_allclose(v0.x, [2, 3, 4, 5, 6])
    np.testing.assert_allclose(v0.t, [0, 0.5, 1, 1.5, 2])
    assert len(s[s.x == 8.0]) == 3  # the standing vehicle's track ends at 2.0 s
    # frame at t = 4.0 s (index 8): vehicle 0 at x = 8 leaves the ROI (x > 9) after 0.5 s;
    # vehicle 1 entered the ROI at y = 1 and is followed for every step
    s = w[w.scenario == 8]
    east = s[s.y == 0.0]
    np.testing.assert_allclose(east.x, [8.0, 9.0])
    north = s[s.x == 5.0]
    np.testing.assert_allclose(north.y, [1.0, 1.5, 2.0, 2.5, 3.0])
    assert set(w.columns) == {"scenario", "vehicle", "t", "x", "y", "vx", "vy"}
    assert w.scenario.nunique() == len(frames)
    narrow = rl.recorded_windows(tracks, frames, 2, roi=(-1.0, 3.0, -1.0, 9.0))
    assert narrow.x.max() <= 3.0


def test_ways_in():
    assert ev.realism is rl.realism
    fresh = subprocess.run(
        [sys.executable, "-c", "import dpgp; print(dpgp.evaluate.realism.__module__)"], capture_output=True, text=True
    )
    assert fresh.stdout.strip() == "dpgp.evaluate.realism_checks", (
        fresh.stderr
    )  # a function, without importing a module first
    tracks = tracks_table()
    frames = dpgp.make_frames(tracks, roi=(-1.0, 9.0, -1.0, 9.0), dt=0.5)
    assert rl.data_units(tracks, frames) is None
    assert rl.data_units(tracks, dpgp.make_frames(tracks, dt=0.5, units="ft->m")) == "m"
    ngsim_like = tracks.copy()
    ngsim_like.attrs["dpgp"] = {"units": "ft", "format": "ngsim"}
    assert rl.data_units(ngsim_like, dpgp.make_frames(ngsim_like, dt=0.5)) == "ft"
    assert rl.data_agent(ngsim_like) == "vehicle"
    ngsim_like.attrs["dpgp"] = {"units": "m", "format": "eth_ucy"}
    assert rl.data_agent(ngsim_like) == "pedestrian"


def test_model_evaluate_and_the_command_line_report_realism(tmp_path):
    tracks = straight_tracks()
    frames = dpgp.make_frames(tracks, roi=(-30.0, 30.0, -30.0, 30.0), dt=0.5)
    train, test = ev.split_in_time(frames)
    model = dpgp.DPGP(iterations=2, noise_var=0.1, length_scale_prior=(10.0, 1.0), seed=0, progress=False).fit(train)
    out = model.evaluate(test, tracks=tracks, horizons=(1,))
    r = out.realism
    assert r is not None and out.table.loc["dpgp", "realism"] == r.scores.loc["meta", "generated"]
    assert out.table.loc["position_blind", "realism"] == r.scores.loc["meta", "blind"]
    assert r.features["generated"].dt == 0.5 and r.features["test"].values["count"].max() <= test.sizes.max()
    assert np.isfinite(r.ratio)
    # reproducible for a seed
    again = model.evaluate(test, tracks=tracks, horizons=(1,)).realism
    pd.testing.assert_frame_equal(r.scores, again.scores)
    assert model.evaluate(test).realism is None  # no tracks, no realism
    data, path = tmp_path / "tracks.csv", tmp_path / "m.npz"
    tracks.to_csv(data, index=False)
    model.save(path)
    png = tmp_path / "realism.png"
    assert (
        main(["evaluate", str(path), str(data), "--horizons", "1", "--agent", "pedestrian", "--realism-plot", str(png)])
        == 0
    )
    assert png.stat().st_size > 0


# --- errors ------------------------------------------------------------------------------------
def test_bad_input_raises_typed_errors():
    good = random_scenarios(1)
    with pytest.raises(dpgp.DataFormatError, match="missing"):
        rl.realism(good.drop(columns="vehicle"), good)
    with pytest.raises(dpgp.DataFormatError):
        rl.realism(good.to_numpy(), good)
    with pytest.raises(dpgp.ShapeError, match="empty"):
        rl.realism(good.iloc[:0], good)
    bad = good.copy()
    bad.loc[3, "x"] = np.nan
    with pytest.raises(dpgp.InvalidInputError, match="NaN"):
        rl.realism(good, bad)
    with pytest.raises(dpgp.DataFormatError, match="not numeric"):
        rl.realism(good.assign(x="a"), good)
    with pytest.raises(dpgp.InvalidInputError, match="twice"):
        rl.realism(pd.concat([good, good.iloc[:1]]), good)
    with pytest.raises(dpgp.InvalidInputError, match="agent"):
        rl.realism(good, good, agent="bicycle")
    with pytest.raises(dpgp.InvalidInputError, match="units"):
        rl.realism(good, good, units="furlong")
    with pytest.raises(dpgp.InvalidInputError, match="collision_distance"):
        rl.realism(good, good, collision_distance=-1.0)
    with pytest.raises(dpgp.InvalidInputError, match="dt"):
        rl.realism(good, good, dt=0)
    with pytest.raises(dpgp.InvalidInputError, match="bins"):
        rl.realism(good, good, bins=0)
    with pytest.raises(dpgp.InvalidInputError, match="dict"):
        rl.realism(good, good, [good])
    with pytest.raises(dpgp.InvalidInputError, match="other names"):
        rl.realism(good, good, {"test": good})
    train = train_frames()
    with pytest.raises(dpgp.InvalidInputError, match="seed"):
        rl.position_blind_scenarios(train, 3, 2, 0.5, seed=-1)
    with pytest.raises(dpgp.InvalidInputError, match="dt"):
        rl.position_blind_scenarios(train, 3, 2, float("nan"))
    with pytest.raises(dpgp.ShapeError):
        rl.position_blind_scenarios(good, 3, 2, 0.5)
    with pytest.raises(dpgp.InvalidInputError, match="steps"):
        rl.recorded_windows(tracks_table(), dpgp.make_frames(tracks_table(), dt=0.5), -1)
    with pytest.raises(dpgp.InvalidInputError, match="pass dt"):
        rl.recorded_windows(tracks_table(), train, 2)
