"""ASAM OpenSCENARIO export: every file written is valid against the OpenSCENARIO 1.2 XSD that
scenariogeneration ships (checked with lxml, and once with scenariogeneration's own xmlschema
check), its trajectories read back with scenariogeneration's reader match the generated table
within 1e-6 m and s, headings match the velocities, vehicles that leave the ROI are deleted when
their rows end, units, origin, sizes, object types and traceability are as documented, and the
template writer gives the same bytes as building every file's object tree.

The oracles are independent of the writer: the generated table itself (``to_pandas``), numpy
headings, and XPath queries on the raw XML."""

from __future__ import annotations

import datetime
import json
import sys
import warnings

import numpy as np
import pandas as pd
import pytest
from lxml import etree

import dpgp
from dpgp.data.framing import FT_TO_M, FramingSummary
from dpgp.exceptions import InvalidInputError
from dpgp.generate import openscenario as osc
from dpgp.generate.scenarios import Scenarios

from conftest import data_file

TOL = 1e-6  # metres and seconds
DATE = datetime.datetime(2026, 1, 2, 3, 4, 5)


def _summary(**extra) -> FramingSummary:
    base = dict(dt=0.5, max_gap=1.0, roi=None, units=None, velocity="columns", smoothing=None, n_rows=0, n_tracks=0,
                n_segments=0, n_gaps=0, n_gap_times=0, n_segments_between_grid_times=0, n_rows_between_grid_times=0,
                n_single_sample_segments=0, n_unsmoothed_segments=0, n_resampled=0, n_outside_roi=0, n_points=0,
                n_frames=0, n_empty_frames=0, n_scenes=1)  # fmt: skip
    return FramingSummary(**{**base, **extra})


@pytest.fixture(scope="module")
def model() -> dpgp.DPGP:
    """A highway model whose frames say they are in feet, of vehicles 15 x 6 ft."""
    frames = dpgp.datasets.synthetic("highway", n_frames=40, seed=3, vehicles=(3, 8))
    frames.summary = _summary(length_unit="ft", object_type="vehicle", object_size=(15.0, 6.0))
    return dpgp.DPGP(iterations=2, seed=0, progress=False).fit(frames)


@pytest.fixture(scope="module")
def scenarios(model) -> Scenarios:
    return model.sample_scenarios(6, steps=20, seed=11)


@pytest.fixture(scope="module")
def written(model, scenarios, tmp_path_factory):
    out = tmp_path_factory.mktemp("xosc")
    paths = scenarios.to_openscenario(out, model, seed=11, description="test model", date=DATE)
    return out, paths


def _expected(scenarios: Scenarios, s: int, scale: float = FT_TO_M, origin=(0.0, 0.0)) -> pd.DataFrame:
    df = scenarios.to_pandas()
    df = df[df["scenario"] == s].sort_values(["vehicle", "t"], kind="stable", ignore_index=True)
    df["x"] = (df["x"] - origin[0]) * scale
    df["y"] = (df["y"] - origin[1]) * scale
    return df


def _same_trajectories(back: pd.DataFrame, want: pd.DataFrame) -> None:
    assert back["vehicle"].tolist() == want["vehicle"].tolist()
    for c in ("t", "x", "y"):
        np.testing.assert_allclose(back[c].to_numpy(), want[c].to_numpy(), rtol=0, atol=TOL, err_msg=c)


def test_one_valid_file_per_scenario(written, scenarios):
    out, paths = written
    assert [p.name for p in paths] == [f"scenario_{s:05d}.xosc" for s in range(len(scenarios))]
    assert sorted(p.name for p in out.iterdir()) == [p.name for p in paths]  # no temporary files left
    for p in paths:
        assert osc.validate(p) == [], p
        assert etree.parse(str(p)).getroot().find("FileHeader").get("revMinor") == "2"


def test_schema_check_catches_an_invalid_file(written, tmp_path):
    """The validator can fail: the same file without its Storyboard is reported."""
    _, paths = written
    doc = etree.parse(str(paths[0]))
    doc.getroot().remove(doc.getroot().find("Storyboard"))
    bad = tmp_path / "bad.xosc"
    doc.write(str(bad))
    assert osc.validate(bad) != []
    (tmp_path / "broken.xosc").write_text("<OpenSCENARIO>")
    assert osc.validate(tmp_path / "broken.xosc")[0].startswith("not well-formed")


def test_scenariogeneration_validates_and_parses_a_file(written, scenarios):
    """scenariogeneration's own entry point: its xmlschema check, then its reader."""
    import xml.etree.ElementTree as ET

    from scenariogeneration import xosc
    from scenariogeneration.xosc.xosc_reader import validate_schema

    _, paths = written
    assert validate_schema(ET.parse(paths[1])) is True
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # ParseOpenScenario warns on a schema-invalid file
        parsed = xosc.ParseOpenScenario(str(paths[1]))
    want = _expected(scenarios, 1)
    got = []
    for group in parsed.storyboard.stories[0].acts[0].maneuvergroup:
        for event in group.maneuvers[0].events:
            action = event.action[0].action
            if isinstance(action, xosc.FollowTrajectoryAction):
                poly = action.trajectory.shapes
                got += [(group.actors.actors[0].entity, t, p.x, p.y) for t, p in zip(poly.time, poly.positions)]
    got_df = pd.DataFrame(got, columns=["entity", "t", "x", "y"])
    moving = want.groupby("vehicle")["t"].transform("size") >= 2
    want = want[moving.to_numpy()]
    assert got_df["entity"].tolist() == [f"vehicle{v}" for v in want["vehicle"]]
    for c in ("t", "x", "y"):
        np.testing.assert_allclose(got_df[c].to_numpy(), want[c].to_numpy(), rtol=0, atol=TOL)


def test_round_trip_within_tolerance(written, scenarios):
    _, paths = written
    for s, p in enumerate(paths):
        _same_trajectories(osc.read_openscenario(p), _expected(scenarios, s))


def test_headings_follow_the_velocity(written, scenarios):
    _, paths = written
    for s, p in enumerate(paths):
        back, want = osc.read_openscenario(p), _expected(scenarios, s)
        moving = np.hypot(want["vx"], want["vy"]).to_numpy() > 1e-9
        expect = np.arctan2(want["vy"], want["vx"]).to_numpy()
        diff = np.angle(np.exp(1j * (back["heading"].to_numpy() - expect)))
        assert np.abs(diff[moving]).max() < 1e-9
        for _, h in back.groupby("vehicle")["heading"]:  # unwrapped: no jump of a half turn
            assert np.all(np.abs(np.diff(h.to_numpy())) < np.pi)


def test_headings_of_standing_vehicles():
    h = osc.headings(np.array([0.0, 0.0, 1.0, 0.0, -1.0, 0.0]), np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0]))
    np.testing.assert_allclose(h, [np.pi / 4, np.pi / 4, np.pi / 4, np.pi / 4, np.pi, np.pi])
    assert osc.headings(np.zeros(3), np.zeros(3)).tolist() == [0.0, 0.0, 0.0]
    # crossing ±π is unwrapped
    h = osc.headings(np.array([-1.0, -1.0]), np.array([0.01, -0.01]))
    assert abs(h[1] - h[0]) < 0.1


def test_headings_of_many_runs_at_once_match_numpy_per_run():
    rng = np.random.default_rng(0)
    lengths = rng.integers(1, 30, size=40)
    starts = np.r_[0, np.cumsum(lengths)[:-1]]
    angle = np.cumsum(rng.normal(0, 1.5, size=lengths.sum()))  # turns often cross ±π
    vx, vy = np.cos(angle), np.sin(angle)
    vx[::7] = vy[::7] = 0.0  # some standing rows
    got = osc.headings(vx, vy, starts)
    for a, n in zip(starts, lengths):
        np.testing.assert_array_equal(got[a : a + n], osc.headings(vx[a : a + n], vy[a : a + n]))
        moving = np.hypot(vx[a : a + n], vy[a : a + n]) > 0
        if moving.all():  # oracle: numpy's unwrap of the velocity angles
            np.testing.assert_allclose(got[a : a + n], np.unwrap(np.arctan2(vy[a : a + n], vx[a : a + n])), atol=1e-12)


def test_vehicles_that_leave_the_roi_are_deleted_when_their_rows_end(written, scenarios):
    _, paths = written
    end = scenarios.to_pandas()["t"].max()
    n_left = 0
    for s, p in enumerate(paths):
        want = _expected(scenarios, s)
        last = want.groupby("vehicle")["t"].max()
        doc = etree.parse(str(p))
        deleted = {}
        for ev in doc.iter("Event"):
            if ev.find(".//DeleteEntityAction") is not None:
                entity = ev.getparent().getparent().find("Actors/EntityRef").get("entityRef")
                deleted[entity] = float(ev.find(".//SimulationTimeCondition").get("value"))
        assert deleted == {f"vehicle{v}": t for v, t in last.items() if t < end}
        assert osc.read_openscenario(p).attrs["deleted"] == deleted
        n_left += len(deleted)
    assert n_left > 0, "no vehicle left the ROI: the test shows nothing"
    stop = float(doc.find("Storyboard/StopTrigger//SimulationTimeCondition").get("value"))
    assert stop == end


def test_units_sizes_and_traceability_come_from_the_model(written, scenarios):
    _, paths = written
    for s, p in enumerate(paths):
        back = osc.read_openscenario(p)
        params = back.attrs["parameters"]
        assert params["dpgp_scenario"] == str(s)
        assert params["dpgp_pattern"] == str(int(scenarios.patterns[s]))
        assert params["dpgp_seed"] == "11"
        assert params["dpgp_units"] == "ft"
        assert float(params["dpgp_dt"]) == scenarios.dt
        assert (
            back.attrs["description"] == f"test model: scenario {s} of 6, pattern {int(scenarios.patterns[s])}, seed 11"
        )
        assert set(back.attrs["kinds"].values()) == {"vehicle"}
        for size in back.attrs["sizes"].values():
            np.testing.assert_allclose(size, (15.0 * FT_TO_M, 6.0 * FT_TO_M, osc.DEFAULT_SIZES["vehicle"][2]))
    root = etree.parse(str(paths[0])).getroot()
    assert root.find("RoadNetwork/LogicFile") is None  # no road network by default
    assert root.find("FileHeader").get("date") == DATE.isoformat()


def test_units_override_origin_and_road_network(model, scenarios, tmp_path):
    one = Scenarios(scenarios.simulations[:1], scenarios.patterns[:1], scenarios.counts[:1])
    (p,) = one.to_openscenario(
        tmp_path / "one.xosc", model, units="m", origin=(2.0, 50.0), road_network="maps/road.xodr"
    )
    assert p == tmp_path / "one.xosc" and osc.validate(p) == []
    back = osc.read_openscenario(p)
    _same_trajectories(back, _expected(one, 0, scale=1.0, origin=(2.0, 50.0)))
    assert back.attrs["parameters"]["dpgp_origin_x"] == "2.0" and back.attrs["parameters"]["dpgp_units"] == "m"
    assert etree.parse(str(p)).getroot().find("RoadNetwork/LogicFile").get("filepath") == "maps/road.xodr"
    (q,) = one.to_openscenario(tmp_path / "q.xosc", model, units=2.0)
    _same_trajectories(osc.read_openscenario(q), _expected(one, 0, scale=2.0))


def test_a_model_without_units_is_written_in_metres_with_a_warning(scenarios, tmp_path):
    one = Scenarios(scenarios.simulations[:1], scenarios.patterns[:1], scenarios.counts[:1])
    with pytest.warns(UserWarning, match="does not record"):
        (p,) = one.to_openscenario(tmp_path / "a.xosc")
    back = osc.read_openscenario(p)
    _same_trajectories(back, _expected(one, 0, scale=1.0))
    assert set(back.attrs["sizes"].values()) == {osc.DEFAULT_SIZES["vehicle"]}
    assert back.attrs["parameters"]["dpgp_seed"] == "none"


def test_pedestrians(scenarios, tmp_path):
    one = Scenarios(scenarios.simulations[:2], scenarios.patterns[:2], scenarios.counts[:2])
    paths = one.to_openscenario(tmp_path, units="m", object_type="pedestrian", size=(0.4, 0.7))
    for p in paths:
        assert osc.validate(p) == []
        root = etree.parse(str(p)).getroot()
        peds = root.findall("Entities/ScenarioObject/Pedestrian")
        assert peds and len(peds) == len(root.findall("Entities/ScenarioObject"))
        assert {e.get("pedestrianCategory") for e in peds} == {"pedestrian"}
        back = osc.read_openscenario(p)
        assert all(name.startswith("pedestrian") for name in back["entity"])
        assert set(back.attrs["sizes"].values()) == {(0.4, 0.7, osc.DEFAULT_SIZES["pedestrian"][2])}


class _Table:
    """What the exporter uses of Scenarios, with a table of our own making."""

    def __init__(self, df: pd.DataFrame, n: int, dt: float = 0.5) -> None:
        self.df, self.patterns, self.dt, self.n = df, np.arange(n), dt, n

    def to_pandas(self) -> pd.DataFrame:
        return self.df

    def __len__(self) -> int:
        return self.n


def test_size_columns_single_rows_and_empty_scenarios(tmp_path):
    """Per-row sizes in the table win; a vehicle with one row is a teleport (and deleted when
    the scenario goes on); a scenario with no vehicle is still a valid file."""
    df = pd.DataFrame({
        "scenario": [0, 0, 0, 0, 2], "vehicle": [0, 0, 0, 1, 0], "t": [0.0, 0.5, 1.0, 0.0, 0.0],
        "x": [0.0, 1.0, 2.0, 5.0, 3.0], "y": [0.0, 0.0, 0.0, 5.0, 3.0], "vx": [2.0, 2.0, 2.0, 0.0, 1.0],
        "vy": [0.0] * 5, "length": [4.0, 4.0, 4.0, 12.0, 4.0], "width": [2.0, 2.0, 2.0, 2.5, 2.0],
    })  # fmt: skip
    paths = osc.write_openscenario(_Table(df, 3), tmp_path, units="m", date=DATE)
    for p in paths:
        assert osc.validate(p) == [], p
    first = osc.read_openscenario(paths[0])
    assert first[["vehicle", "t", "x"]].values.tolist() == [[0, 0.0, 0.0], [0, 0.5, 1.0], [0, 1.0, 2.0], [1, 0.0, 5.0]]
    assert first.attrs["deleted"] == {"vehicle1": 0.0}
    assert first.attrs["sizes"]["vehicle1"][:2] == (12.0, 2.5)
    empty = etree.parse(str(paths[1])).getroot()
    assert empty.find("Entities/ScenarioObject") is None and empty.find("Storyboard/Story") is None
    # scenario 2: one vehicle with one row, before the end: a teleport, no trajectory, deleted
    third = etree.parse(str(paths[2])).getroot()
    assert third.find(".//FollowTrajectoryAction") is None
    assert osc.read_openscenario(paths[2]).attrs["deleted"] == {"vehicle0": 0.0}


def test_template_writes_the_same_bytes_as_the_object_tree(written, scenarios, model):
    """The fast path (text cut from one scenariogeneration file) against building each file's
    scenariogeneration object tree and serialising it."""
    from scenariogeneration import xosc

    _, paths = written
    df = scenarios.to_pandas().sort_values(["scenario", "vehicle", "t"], kind="stable")
    header = {"seed": "11", "dt": scenarios.dt, "units": "ft", "origin": (0.0, 0.0), "version": dpgp.__version__,
              "date": DATE, "end": float(df["t"].max()), "road": None}  # fmt: skip
    for s, p in enumerate(paths):
        part = {c: df[c].to_numpy()[df["scenario"].to_numpy() == s] for c in df.columns}
        objs = osc._objects(part, header["end"], FT_TO_M, (0.0, 0.0), "vehicle", (15.0 * FT_TO_M, 6.0 * FT_TO_M, 1.5))
        text = f"test model: scenario {s} of 6, pattern {int(scenarios.patterns[s])}, seed 11"
        tree = osc._scenario(xosc, objs, header, s, int(scenarios.patterns[s]), text).get_element()
        assert osc._serialize(tree) == p.read_bytes()


def test_same_inputs_give_the_same_files(model, scenarios, written, tmp_path):
    _, paths = written
    again = scenarios.to_openscenario(tmp_path, model, seed=11, description="test model", date=DATE)
    assert [p.read_bytes() for p in again] == [p.read_bytes() for p in paths]


def test_descriptions_are_escaped(scenarios, tmp_path):
    one = Scenarios(scenarios.simulations[:1], scenarios.patterns[:1], scenarios.counts[:1])
    (p,) = one.to_openscenario(tmp_path / "e.xosc", units="m", description='a & b <c> "d"')
    assert osc.validate(p) == []
    assert etree.parse(str(p)).getroot().find("FileHeader").get("description").startswith('a & b <c> "d": scenario 0')


@pytest.mark.parametrize(
    "options, match",
    [
        ({"units": "yards"}, "units"),
        ({"units": -1.0}, "units"),
        ({"origin": (1.0,)}, "origin"),
        ({"origin": (float("nan"), 0.0)}, "origin"),
        ({"size": (4.0, -1.0)}, "size"),
        ({"size": "big"}, "size"),
        ({"object_type": "bicycle"}, "object_type"),
        ({"seed": "7"}, "seed"),
    ],
)
def test_bad_arguments(scenarios, tmp_path, options, match):
    with pytest.raises(InvalidInputError, match=match):
        scenarios.to_openscenario(tmp_path, **{"units": "m", **options})


def test_non_finite_positions_are_refused(tmp_path):
    df = pd.DataFrame({"scenario": [0, 0], "vehicle": [0, 0], "t": [0.0, 0.5], "x": [0.0, np.nan], "y": [0.0, 1.0],
                       "vx": [1.0, 1.0], "vy": [0.0, 0.0]})  # fmt: skip
    with pytest.raises(InvalidInputError, match="'x'"):
        osc.write_openscenario(_Table(df, 1), tmp_path, units="m")
    assert list(tmp_path.iterdir()) == []


def test_one_file_for_many_scenarios_is_refused(scenarios, tmp_path):
    with pytest.raises(InvalidInputError, match="directory"):
        scenarios.to_openscenario(tmp_path / "all.xosc", units="m")
    assert not (tmp_path / "all.xosc").exists()


def test_missing_scenariogeneration_says_what_to_install(scenarios, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "scenariogeneration", None)
    with pytest.raises(ImportError, match=r"pip install 'dpgp\[openscenario\]'"):
        scenarios.to_openscenario(tmp_path, units="m")


def test_model_file_keeps_units_type_and_size(model, tmp_path):
    path = tmp_path / "m.npz"
    model.save(path)
    s = dpgp.DPGP.load(path).frames_.summary
    assert (s.length_unit, s.object_type, s.object_size) == ("ft", "vehicle", (15.0, 6.0))


def test_old_model_files_and_newer_summary_keys_load(model, tmp_path):
    from model_files import _rewrite_metadata

    path = tmp_path / "m.npz"
    model.save(path)

    def old(meta):  # written before the summary recorded units, plus a key from a newer writer
        for key in ("length_unit", "object_type", "object_size"):
            del meta["frames_summary"][key]
        meta["frames_summary"]["something_newer"] = 1

    _rewrite_metadata(path, tmp_path / "old.npz", old)
    s = dpgp.DPGP.load(tmp_path / "old.npz").frames_.summary
    assert (s.length_unit, s.object_type, s.object_size) == (None, None, None)
    assert json.loads(json.dumps(s.to_dict()))["dt"] == 0.5


def test_make_frames_records_units_type_and_size():
    tracks = dpgp.read_ngsim(data_file("ngsim_peachtree_raw.csv"))
    per_track = tracks.groupby("track")[["v_length", "v_Width"]].first()  # oracle: pandas
    feet = dpgp.make_frames(tracks, roi=(-20, 30, 0, 80), dt=0.5).summary
    assert (feet.length_unit, feet.object_type) == ("ft", "vehicle")
    np.testing.assert_allclose(feet.object_size, (per_track["v_length"].median(), per_track["v_Width"].median()))
    metres = dpgp.make_frames(tracks, roi=(-20, 30, 0, 80), dt=0.5, units="ft->m").summary
    assert metres.length_unit == "m"
    np.testing.assert_allclose(metres.object_size, np.array(feet.object_size) * FT_TO_M)
    assert dpgp.make_frames(tracks, roi=(-20, 30, 0, 80), dt=0.5, units=2.0).summary.length_unit is None
    eth = dpgp.make_frames(dpgp.read_tracks(data_file("eth_ucy_biwi_eth.txt"), preset="eth_ucy"), dt=0.4).summary
    assert (eth.length_unit, eth.object_type, eth.object_size) == ("m", "pedestrian", None)
    plain = pd.DataFrame({"track": [0, 0, 1, 1], "t": [0.0, 0.5, 0.0, 0.5], "x": [0.0, 1, 2, 3], "y": [0.0, 0, 0, 0]})
    s = dpgp.make_frames(plain, dt=0.5).summary
    assert (s.length_unit, s.object_type, s.object_size) == (None, None, None)


def test_cli_generate_xosc(model, tmp_path, capsys):
    from dpgp.cli import main

    path = tmp_path / "m.npz"
    model.save(path)
    out = tmp_path / "out"
    assert main(["generate", str(path), "-n", "2", "--steps", "6", "-o", str(out), "--format", "xosc", "--seed", "5",
                 "--origin", "1", "2", "--road-network", "road.xodr"]) == 0  # fmt: skip
    assert "wrote 2 OpenSCENARIO file(s)" in capsys.readouterr().out
    files = sorted(out.iterdir())
    assert len(files) == 2 and all(osc.validate(p) == [] for p in files)
    again = model.sample_scenarios(2, steps=6, seed=5)
    back = osc.read_openscenario(files[1])
    _same_trajectories(back, _expected(again, 1, origin=(1.0, 2.0)))
    assert back.attrs["parameters"]["dpgp_seed"] == "5" and "m.npz" in back.attrs["description"]
    # without --seed the file still records the seed it was made with
    assert main(["generate", str(path), "-n", "1", "--steps", "3", "-o", str(tmp_path / "one.xosc")]) == 0
    assert osc.read_openscenario(tmp_path / "one.xosc").attrs["parameters"]["dpgp_seed"].isdigit()
    assert main(["generate", str(path), "-n", "2", "--steps", "3", "-o", str(tmp_path / "two.xosc")]) == 1
    assert "give a directory" in capsys.readouterr().err
