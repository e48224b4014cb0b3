"""The ``dpgp`` command: every subcommand end to end in a temporary directory, --help for each,
and errors as one line with a non-zero exit status (no traceback)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

import dpgp
from dpgp.cli import main

COMMANDS = ("fit", "info", "plot", "simulate", "generate", "demo")


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    data = d / "frames.csv"
    dpgp.datasets.synthetic("intersection", n_frames=36, seed=8).to_pandas().to_csv(data, index=False)
    out = d / "model.npz"
    assert main(["fit", str(data), "-o", str(out), "--iterations", "2", "--seed", "3", "--no-progress"]) == 0
    return out


def _tracks(path) -> None:
    """Twelve vehicles on straight lines for 20 s at 10 Hz: northbound fast, eastbound slow."""
    rows = []
    t = np.arange(0, 20, 0.1)
    for v in range(12):
        start = v * 1.5
        if v % 2:
            x, y = np.full_like(t, 3.0), -50 + 8.0 * (t - start)
        else:
            x, y = -50 + 4.0 * (t - start), np.full_like(t, -3.0)
        keep = t >= start
        rows.append(pd.DataFrame({"track": v, "t": t[keep], "x": x[keep], "y": y[keep]}))
    pd.concat(rows).to_csv(path, index=False)


def test_fit_writes_a_model(model_file, capsys):
    model = dpgp.DPGP.load(model_file)
    assert len(model.frames_) == 36 and model.n_iter_ == 2 and model.seed == 3 and not model.progress


def test_fit_frames_raw_tracks_with_roi_and_dt(tmp_path, capsys):
    _tracks(tmp_path / "tracks.csv")
    out = tmp_path / "m.npz"
    code = main(["fit", str(tmp_path / "tracks.csv"), "-o", str(out), "--roi", "-50", "50", "-50", "50", "--dt", "1.0",
                 "--iterations", "1", "--assignment", "map", "--max-frames", "15", "--no-progress"])  # fmt: skip
    assert code == 0
    model = dpgp.DPGP.load(out)
    assert len(model.frames_) == 15
    assert model.frames_.summary.dt == 1.0 and model.frames_.summary.roi == (-50.0, 50.0, -50.0, 50.0)
    assert model.assignment == "map"
    np.testing.assert_allclose(np.diff(np.unique(model.frames_.ids)), 1.0)  # frames every --dt seconds
    assert model.frames_.xy.min() >= -50 and model.frames_.xy.max() <= 50
    assert "fitted" in capsys.readouterr().out


def test_fit_framed_input_with_roi_and_dt(tmp_path):
    data = tmp_path / "frames.csv"
    dpgp.datasets.synthetic("highway", n_frames=20, seed=1).to_pandas().to_csv(data, index=False)
    out = tmp_path / "m.npz"
    assert main(["fit", str(data), "-o", str(out), "--format", "frames", "--roi", "0", "16", "0", "100", "--dt", "0.1",
                 "--iterations", "1", "--no-progress"]) == 0  # fmt: skip
    model = dpgp.DPGP.load(out)
    assert model.frames_.xy[:, 1].max() <= 100 and model.frames_.summary.dt == 0.1
    assert model.simulate(0, steps=2).dt == pytest.approx(0.1)


def test_info(model_file, capsys):
    assert main(["info", str(model_file), "--top", "2"]) == 0
    out = capsys.readouterr().out
    model = dpgp.DPGP.load(model_file)
    assert "dpgp-model format 2" in out and "36 frames" in out
    assert f"patterns: {model.n_patterns_}" in out and "settings:" in out
    n = model.noise_var_
    assert f"noise variance per pattern (frame-weighted median ({n[0]:.4g}, {n[1]:.4g}); sampled in the chain" in out


def test_plot(model_file, tmp_path, capsys):
    out = tmp_path / "figs"
    assert main(["plot", str(model_file), "--out", str(out), "--kind", "weights", "field", "animation",
                 "--patterns", "2", "--steps", "5", "--dpi", "40"]) == 0  # fmt: skip
    written = sorted(p.name for p in out.iterdir())
    assert written == ["field_0.png", "field_1.png", "simulation.gif", "weights.png"]
    assert all((out / n).stat().st_size > 1000 for n in written)
    assert capsys.readouterr().out.count("wrote") == 4


def test_simulate(model_file, tmp_path, capsys):
    out = tmp_path / "sim.csv"
    assert main(["simulate", str(model_file), "--frame", "4", "-o", str(out), "--steps", "6", "--method", "rk4"]) == 0
    df = pd.read_csv(out)
    model = dpgp.DPGP.load(model_file)
    sim = model.simulate(4, steps=6, method="rk4")
    assert len(df) == 7 * len(model.frames_[4])
    np.testing.assert_array_equal(df["x"].to_numpy().reshape(7, -1), sim.positions[..., 0])
    out2 = tmp_path / "sim2.csv"
    assert (
        main(
            [
                "simulate",
                str(model_file),
                "--frame",
                "4",
                "-o",
                str(out2),
                "--steps",
                "3",
                "--stochastic",
                "--seed",
                "1",
            ]
        )
        == 0
    )
    assert pd.read_csv(out2)["low_data"].dtype == bool


def test_generate_long_scenarios(tmp_path, capsys):
    _tracks(tmp_path / "tracks.csv")
    model = tmp_path / "m.npz"
    assert main(["fit", str(tmp_path / "tracks.csv"), "-o", str(model), "--dt", "0.5", "--iterations", "2",
                 "--seed", "1", "--no-progress"]) == 0  # fmt: skip
    out = tmp_path / "long.csv"
    assert (
        main(["generate", str(model), "-n", "2", "-o", str(out), "--duration", "10", "--phases", "2", "--seed", "3"])
        == 0
    )
    df = pd.read_csv(out)
    assert list(df.columns) == ["scenario", "vehicle", "t", "x", "y", "vx", "vy", "pattern", "phase"]
    assert set(df["scenario"]) == {0, 1} and df["t"].max() <= 10.0 and set(df["phase"]) <= {0, 1}
    said = capsys.readouterr().out
    assert "long scenario(s) of 10 s" in said and "stop line(s) learned from the recorded queues" in said
    # without the stop lines and free speeds nothing is said of them; they need phases
    free = tmp_path / "free.csv"
    args = ["generate", str(model), "-n", "2", "-o", str(free), "--duration", "10", "--phases", "2", "--seed", "3"]
    assert main([*args, "--no-stop-lines"]) == 0
    assert "stop line" not in capsys.readouterr().out
    assert (
        main(["generate", str(model), "-n", "1", "-o", str(tmp_path / "n.csv"), "--duration", "5", "--no-stop-lines"])
        == 1
    )
    assert "--phases" in capsys.readouterr().err
    plain = tmp_path / "plain.csv"
    assert main(["generate", str(model), "-n", "1", "-o", str(plain), "--duration", "5", "--seed", "3"]) == 0
    assert "phase" not in pd.read_csv(plain).columns
    # --ego in long scenarios: the first vehicle to come to the point, a column; none placed there
    egoed = tmp_path / "ego.csv"
    assert main(["generate", str(model), "-n", "2", "-o", str(egoed), "--duration", "5", "--seed", "3",
                 "--ego", "20", "20"]) == 0  # fmt: skip
    df = pd.read_csv(egoed)
    assert df["ego"].dtype == bool and (df[df["ego"]].groupby("scenario")["vehicle"].nunique() <= 1).all()
    assert "an ego vehicle (the first to come to the point)" in capsys.readouterr().out
    assert main(["generate", str(model), "-n", "1", "-o", str(tmp_path / "p.csv"), "--duration", "5",
                 "--ego", "20", "20", "--place-ego"]) == 1  # fmt: skip
    assert "--place-ego" in capsys.readouterr().err and not (tmp_path / "p.csv").exists()
    assert main(["generate", str(model), "-n", "1", "-o", str(tmp_path / "x.csv"), "--phases", "2"]) == 1
    assert "--duration" in capsys.readouterr().err
    assert (
        main(["generate", str(model), "-n", "1", "-o", str(tmp_path / "x.out"), "--duration", "5", "--format", "sumo"])
        == 1
    )
    assert "CSV" in capsys.readouterr().err
    assert (
        main(["generate", str(model), "-n", "1", "-o", str(tmp_path / "y.csv"), "--duration", "5", "--phases", "two"])
        == 1
    )
    assert "--phases" in capsys.readouterr().err
    assert not (tmp_path / "x.out").exists() and not (tmp_path / "x.csv").exists()
    # the stages of a fixed cycle
    cyc = tmp_path / "cycle.csv"
    args = ["generate", str(model), "-n", "1", "-o", str(cyc), "--duration", "10", "--phases", "2", "--cycle"]
    assert main([*args, "--seed", "3"]) == 0
    assert set(pd.read_csv(cyc)["phase"]) <= {0, 1}
    for bad, said in ((["--duration", "5", "--cycle"], "--phases"), (["--cycle"], "--duration")):
        assert main(["generate", str(model), "-n", "1", "-o", str(tmp_path / "z.csv"), *bad]) == 1
        assert said in capsys.readouterr().err
    assert not (tmp_path / "z.csv").exists()


def test_generate_csv_and_sumo(model_file, tmp_path):
    csv = tmp_path / "scen.csv"
    assert main(["generate", str(model_file), "-n", "3", "-o", str(csv), "--steps", "5", "--seed", "2"]) == 0
    df = pd.read_csv(csv)
    assert list(df.columns) == ["scenario", "vehicle", "t", "x", "y", "vx", "vy"]
    assert set(df["scenario"]) <= {0, 1, 2} and len(df) > 0
    xml = tmp_path / "scen.out"
    assert main(["generate", str(model_file), "-n", "3", "-o", str(xml), "--format", "sumo", "--steps", "5",
                 "--seed", "2", "--pattern", "0"]) == 0  # fmt: skip
    tracks = dpgp.read_tracks(xml, preset="sumo")
    assert tracks["id"].str.match(r"s\d+_v\d+").all()
    # --ego: each scenario's vehicle nearest the point is its ego, s<scenario>_ego
    ego = tmp_path / "ego.out"
    args = ["generate", str(model_file), "-n", "3", "-o", str(ego), "--format", "sumo", "--steps", "5", "--seed", "2"]
    assert main([*args, "--ego", "0", "0"]) == 0
    ids = set(dpgp.read_tracks(ego, preset="sumo")["id"])
    assert {f"s{s}_ego" for s in range(3)} <= ids
    assert main([*args, "--ego", "0"]) == 1  # a point needs two coordinates
    # --place-ego: a vehicle placed at the point in every scenario is the ego
    x0, x1, y0, y1 = dpgp.DPGP.load(model_file)._fitted().roi
    at = (0.5 * (x0 + x1), 0.5 * (y0 + y1))
    assert main([*args, "--ego", str(at[0]), str(at[1]), "--place-ego"]) == 0
    placed = dpgp.read_tracks(ego, preset="sumo")
    first = placed[placed["id"].str.endswith("_ego")].sort_values("t").groupby("id").head(1)
    assert len(first) == 3 and np.allclose(first[["x", "y"]].to_numpy(), at, atol=1e-2)
    assert main([*args, "--place-ego"]) == 1  # placed where? --ego X Y
    # --critical: tilted toward an event, a table of weights and measures beside the output
    crit = tmp_path / "crit.csv"
    base = ["generate", str(model_file), "-n", "6", "-o", str(crit), "--steps", "4", "--seed", "1"]
    assert main([*base, "--critical", "gap<1.0"]) == 0
    table = pd.read_csv(tmp_path / "crit.critical.csv")
    assert len(table) == 6 and (table["weight"] > 0).all()
    assert {"ttc", "gap", "pet", "collision", "deceleration", "event", "source_frame"} <= set(table.columns)
    np.testing.assert_array_equal(table["event"], table["gap"] < 1.0)
    assert set(pd.read_csv(crit)["scenario"]) <= set(range(6))
    assert main([*base, "--critical", "speed<3"]) == 1  # an event it does not know
    assert main([*base, "--critical", "gap<1.0", "--pattern", "0"]) == 1
    # a generated SUMO file is valid input for a new fit
    assert (
        main(
            [
                "fit",
                str(xml),
                "-o",
                str(tmp_path / "again.npz"),
                "--format",
                "sumo",
                "--iterations",
                "1",
                "--no-progress",
            ]
        )
        == 0
    )


def test_demo(tmp_path, capsys):
    out = tmp_path / "demo"
    assert (
        main(["demo", "--out", str(out), "--frames", "24", "--iterations", "2", "--steps", "6", "--no-progress"]) == 0
    )
    names = {p.name for p in out.iterdir()}
    assert {
        "model.npz",
        "weights.png",
        "trace.png",
        "simulation.png",
        "simulation.gif",
        "field_0.png",
        "frames_0.png",
    } <= names
    printed = capsys.readouterr().out
    assert all(f"wrote {out / n}" in printed for n in names)
    assert "true: 4" in printed


@pytest.mark.parametrize("command", COMMANDS)
def test_help(command, capsys):
    with pytest.raises(SystemExit) as e:
        main([command, "--help"])
    assert e.value.code == 0
    text = capsys.readouterr().out
    assert text.startswith(f"usage: dpgp {command}")
    expected = {"fit": "--iterations", "info": "--top", "plot": "--kind", "simulate": "--frame",
                "generate": "--format", "demo": "--frames"}  # fmt: skip
    assert expected[command] in text


def _error(capsys, argv) -> str:
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.startswith("dpgp: error: ") and err.count("\n") == 1 and "Traceback" not in err
    return err


def test_errors_are_one_line(model_file, tmp_path, capsys):
    assert "no such file" in _error(capsys, ["fit", str(tmp_path / "missing.csv"), "-o", str(tmp_path / "m.npz")])
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    _error(capsys, ["fit", str(bad), "-o", str(tmp_path / "m.npz"), "--format", "frames", "--no-progress"])
    (tmp_path / "broken.npz").write_bytes(model_file.read_bytes()[:500])
    assert "truncated or corrupted" in _error(capsys, ["info", str(tmp_path / "broken.npz")])
    assert "out of range" in _error(
        capsys, ["simulate", str(model_file), "--frame", "999", "-o", str(tmp_path / "s.csv")]
    )
    _error(capsys, ["generate", str(model_file), "-n", "-2", "-o", str(tmp_path / "g.csv")])
    _error(capsys, ["simulate", str(model_file), "--frame", "0", "-o", str(tmp_path / "no" / "dir" / "s.csv")])
    assert not (tmp_path / "m.npz").exists()


def test_console_entry_point_reports_errors_without_traceback(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "dpgp.cli", "info", str(tmp_path / "nope.npz")], capture_output=True, text=True
    )
    assert r.returncode == 1 and r.stderr.startswith("dpgp: error:") and "Traceback" not in r.stderr
    r = subprocess.run([sys.executable, "-m", "dpgp.cli", "frobnicate"], capture_output=True, text=True)
    assert r.returncode == 2 and "invalid choice" in r.stderr
