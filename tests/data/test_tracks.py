"""Readers: read_ngsim on the real Peachtree export and every NGSIM schema, read_tracks with its
presets (ETH/UCY, INTERACTION, highD, inD, SUMO XML and CSV), file types, and bad input."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import dpgp

from conftest import data_file as real


def assert_tracks_table(df: pd.DataFrame) -> None:
    """The documented invariants of a tracks table."""
    assert list(df.columns[:4]) == ["track", "t", "x", "y"]
    assert df["track"].dtype == np.int64 and df["t"].dtype == np.float64
    tr, t = df["track"].to_numpy(), df["t"].to_numpy()
    assert np.all(np.diff(tr) >= 0), "rows sorted by track"
    same = tr[1:] == tr[:-1]
    assert np.all(np.diff(t)[same] > 0), "time strictly increases inside a track"
    assert np.isfinite(df[["t", "x", "y"]].to_numpy()).all()


# --- NGSIM -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def peachtree() -> pd.DataFrame:
    return dpgp.read_ngsim(real("ngsim_peachtree_raw.csv"))


def test_peachtree_loads_with_its_quirks(peachtree):
    df = peachtree
    assert len(df) == 10_000
    assert_tracks_table(df)
    # byte-order mark: the first column is found under its real name
    assert "Vehicle_ID" in df.columns and not any(str(c).startswith("\ufeff") for c in df.columns)
    # thousands separator inside quotes: "1,156" read as the number 1156
    assert df["Total_Frames"].dtype.kind == "i" and 1156 in set(df["Total_Frames"])
    # time from Frame_ID, not Global_Time
    assert np.allclose(df["t"], df["Frame_ID"] * 0.1)
    assert "v_Vel" in df.columns and "vx" not in df.columns  # a speed, not a vector
    assert df.attrs["dpgp"]["units"] == "ft"
    # x, y are Local_X, Local_Y
    raw = pd.read_csv(real("ngsim_peachtree_raw.csv"), encoding="utf-8-sig", thousands=",")
    raw = raw.sort_values(["Vehicle_ID", "Total_Frames", "Frame_ID"], ignore_index=True)
    assert np.array_equal(df["x"].to_numpy(), raw["Local_X"].to_numpy())
    assert np.array_equal(df["y"].to_numpy(), raw["Local_Y"].to_numpy())


def test_a_tracks_table_reads_back_unchanged(peachtree):
    again = dpgp.read_tracks(peachtree)
    assert list(again.columns) == list(peachtree.columns)
    assert again.drop(columns="Location").equals(peachtree.drop(columns="Location"))


def test_peachtree_reused_vehicle_ids_are_split(peachtree):
    df = peachtree
    # 223 Vehicle_IDs, 229 trips: Vehicle_ID 70 (and five more) names two unrelated vehicles,
    # two of them in the same frames (397..)
    assert df["Vehicle_ID"].nunique() == 223 and df["track"].nunique() == 229
    v70 = df[df["Vehicle_ID"] == 70]
    assert v70["track"].nunique() == 2
    for _, g in v70.groupby("track"):
        assert np.all(np.diff(g["Frame_ID"]) == 1) and g["Total_Frames"].nunique() == 1
    assert df.attrs["dpgp"]["report"]["vehicle_ids_with_several_tracks"] == 6


def test_ngsim_txt_forms_match_the_csv(tmp_path, peachtree):
    """The original whitespace-separated .txt (24 columns, no header) reads to the same tracks."""
    raw = pd.read_csv(real("ngsim_peachtree_raw.csv"), encoding="utf-8-sig", thousands=",")
    path = tmp_path / "peachtree.txt"
    raw.iloc[:, :24].to_csv(path, sep=" ", header=False, index=False)
    txt = dpgp.read_ngsim(path)
    for col in ("track", "t", "x", "y", "Vehicle_ID", "Space_Headway", "O_Zone"):
        assert np.array_equal(txt[col].to_numpy(), peachtree[col].to_numpy()), col


def _ngsim_rows(n=30):
    """Two vehicles, 10 Hz, US-101 style (18 columns)."""
    rows = []
    for vid, x0 in ((7, 10.0), (9, 22.0)):
        for k in range(n):
            rows.append(
                [
                    vid,
                    100 + k,
                    n,
                    1113433135300 + 100 * k,
                    x0,
                    50.0 + 3.0 * k,
                    6451203.0,
                    1873252.0,
                    14.5,
                    4.9,
                    2,
                    30.0,
                    0.0,
                    2,
                    0,
                    0,
                    0.0,
                    0.0,
                ]
            )
    return rows


def test_ngsim_us101_txt_without_header(tmp_path):
    path = tmp_path / "trajectories-0750am-0805am.txt"
    path.write_text("\n".join("   ".join(str(v) for v in r) for r in _ngsim_rows()) + "\n")
    df = dpgp.read_ngsim(path)
    assert_tracks_table(df)
    assert df["track"].nunique() == 2 and len(df) == 60
    assert "Space_Headway" in df.columns and "v_length" in df.columns
    assert np.allclose(df["t"].iloc[:2], [10.0, 10.1])
    assert np.allclose(np.diff(df["y"].iloc[:5]), 3.0)


def test_ngsim_column_name_variants(tmp_path):
    names = (
        "Vehicle_ID Frame_ID Total_Frames Global_Time Local_X Local_Y Global_X Global_Y v_Length v_Width "
        "v_Class v_Vel v_Acc Lane_ID Origin_Zone Destination_Zone Int_ID Section_ID Direction Movement "
        "Preceding Following Space_Hdwy Time_Hdwy"
    ).split()
    rows = [r[:14] + [101, 201, 1, 2, 2, 1] + r[14:] for r in _ngsim_rows()]
    path = tmp_path / "lankershim.csv"
    pd.DataFrame(rows, columns=[n.lower() if i % 3 == 0 else n for i, n in enumerate(names)]).to_csv(path, index=False)
    df = dpgp.read_ngsim(path)
    for canon in ("Vehicle_ID", "v_length", "O_Zone", "D_Zone", "Space_Headway", "Time_Headway", "Movement"):
        assert canon in df.columns, canon
    assert df["track"].nunique() == 2


def test_ngsim_time_jump_splits_a_trip(tmp_path):
    rows = _ngsim_rows()
    for r in rows[15:30]:  # vehicle 7 vanishes for 5 s, comes back with the same id
        r[1] += 50
    path = tmp_path / "jump.txt"
    path.write_text("\n".join(" ".join(map(str, r)) for r in rows))
    df = dpgp.read_ngsim(path)
    assert df["track"].nunique() == 3
    assert df.attrs["dpgp"]["report"]["trips_split_at_time_jumps"] == 1
    assert dpgp.read_ngsim(path, split_gap=10.0)["track"].nunique() == 2


def test_ngsim_duplicates(tmp_path):
    rows = _ngsim_rows()
    exact = tmp_path / "dup.txt"
    exact.write_text("\n".join(" ".join(map(str, r)) for r in rows + rows[:3]))
    df = dpgp.read_ngsim(exact)
    assert len(df) == 60 and df.attrs["dpgp"]["report"]["exact_duplicate_rows_dropped"] == 3
    clash = [list(r) for r in rows[:1]]
    clash[0][4] += 1.0  # same vehicle, same frame, another position
    bad = tmp_path / "clash.txt"
    bad.write_text("\n".join(" ".join(map(str, r)) for r in rows + clash))
    with pytest.raises(dpgp.DataFormatError, match="same vehicle trip at the same frame"):
        dpgp.read_ngsim(bad)


def test_ngsim_rejects_other_files(tmp_path):
    with pytest.raises(dpgp.DataFormatError, match="not an NGSIM trajectory file"):
        dpgp.read_ngsim(real("ngsim_lankershim_frames.csv"))
    odd = tmp_path / "odd.txt"
    odd.write_text("1 2 3\n4 5 6\n")
    with pytest.raises(dpgp.DataFormatError, match="18 .* 24"):
        dpgp.read_ngsim(odd)
    with pytest.raises(FileNotFoundError):
        dpgp.read_ngsim(tmp_path / "missing.csv")
    with pytest.raises(dpgp.InvalidInputError, match="split_gap"):
        dpgp.read_ngsim(odd, split_gap=0)


# --- presets -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "name,rows,peds", [("eth_ucy_biwi_eth.txt", 5492, 360), ("eth_ucy_crowds_zara01.txt", 5153, 148)]
)
def test_eth_ucy_preset(name, rows, peds):
    df = dpgp.read_tracks(real(name), preset="eth_ucy")
    assert_tracks_table(df)
    assert len(df) == rows and df["track"].nunique() == peds
    assert np.allclose(df["t"], df["frame"] * 0.04)  # frame step 10 = 0.4 s
    steps = np.diff(df["t"].to_numpy())[np.diff(df["track"].to_numpy()) == 0]
    assert np.isclose(np.median(steps), 0.4)
    assert df.attrs["dpgp"]["units"] == "m"


def test_interaction_preset_keeps_cases_apart(tmp_path):
    path = tmp_path / "vehicle_tracks_000.csv"
    rows = []
    for case in (1, 2):
        for tid in (1, 2):
            for f in range(1, 11):
                rows.append([case, tid, f, 100 * f, "car", 10.0 * case + tid, 0.5 * f, 5.0, 0.0, 0.0, 4.5, 1.8])
    cols = "case_id,track_id,frame_id,timestamp_ms,agent_type,x,y,vx,vy,psi_rad,length,width".split(",")
    pd.DataFrame(rows, columns=cols).to_csv(path, index=False)
    df = dpgp.read_tracks(path, preset="interaction")
    assert_tracks_table(df)
    assert df["track"].nunique() == 4  # track_id restarts in each case
    assert list(df.columns[:7]) == ["track", "t", "x", "y", "vx", "vy", "scene"]
    assert set(df["scene"]) == {1, 2} and "case_id" in df.columns and "agent_type" in df.columns
    assert np.allclose(df["t"].iloc[:3], [0.1, 0.2, 0.3])
    frames = dpgp.make_frames(df, dt=0.1)
    assert len(frames) == 20  # 10 times x 2 cases, never mixed
    assert all(len(f) == 2 for f in frames) and frames.ids[0] == (1, 0.1)


def test_highd_and_ind_presets(tmp_path):
    n = 50
    hd = pd.DataFrame(
        {
            "frame": np.tile(np.arange(1, n + 1), 2),
            "id": np.repeat([1, 2], n),
            "x": np.r_[np.arange(n) * 1.2, 400 - np.arange(n) * 1.0],
            "y": np.repeat([10.0, 20.0], n),
            "width": 4.5,
            "height": 1.9,
            "xVelocity": np.repeat([30.0, -25.0], n),
            "yVelocity": 0.0,
        }
    )
    hd.to_csv(tmp_path / "01_tracks.csv", index=False)
    df = dpgp.read_tracks(tmp_path / "01_tracks.csv", preset="highd")
    assert_tracks_table(df)
    assert np.allclose(df["t"].iloc[:2], [1 / 25, 2 / 25]) and df["vx"].iloc[0] == 30.0
    ind = hd.rename(columns={"id": "trackId", "x": "xCenter", "y": "yCenter"}).assign(recordingId=7)
    df2 = dpgp.read_tracks(ind, preset="ind")
    assert np.array_equal(df2[["t", "x", "y", "vx", "vy"]].to_numpy(), df[["t", "x", "y", "vx", "vy"]].to_numpy())


SUMO_XML = """<?xml version="1.0" encoding="UTF-8"?>
<fcd-export xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance">
    <timestep time="0.00">
        <vehicle id="east" x="10.00" y="5.00" angle="90.00" type="DEFAULT_VEHTYPE" speed="10.00" pos="5.10" lane="e1_0" slope="0.00"/>
        <vehicle id="north" x="50.00" y="0.00" angle="0.00" type="DEFAULT_VEHTYPE" speed="4.00" pos="5.10" lane="e2_0" slope="0.00"/>
    </timestep>
    <timestep time="1.00">
        <vehicle id="east" x="20.00" y="5.00" angle="90.00" type="DEFAULT_VEHTYPE" speed="10.00" pos="15.10" lane="e1_0" slope="0.00"/>
        <vehicle id="north" x="50.00" y="4.00" angle="0.00" type="DEFAULT_VEHTYPE" speed="4.00" pos="9.10" lane="e2_0" slope="0.00"/>
        <person id="p0" x="1.00" y="1.00" angle="225.00" speed="1.41" pos="0.0" edge="e1" slope="0.00"/>
    </timestep>
    <timestep time="2.00">
        <vehicle id="east" x="30.00" y="5.00" angle="90.00" type="DEFAULT_VEHTYPE" speed="10.00" pos="25.10" lane="e1_0" slope="0.00"/>
        <person id="p0" x="0.00" y="0.00" angle="225.00" speed="1.41" pos="1.4" edge="e1" slope="0.00"/>
    </timestep>
    <timestep time="3.00"/>
</fcd-export>
"""

SUMO_CSV = """timestep_time;vehicle_angle;vehicle_id;vehicle_lane;vehicle_pos;vehicle_slope;vehicle_speed;vehicle_type;vehicle_x;vehicle_y;person_angle;person_edge;person_id;person_pos;person_slope;person_speed;person_x;person_y
0.00;90.00;east;e1_0;5.10;0.00;10.00;DEFAULT_VEHTYPE;10.00;5.00;;;;;;;;
0.00;0.00;north;e2_0;5.10;0.00;4.00;DEFAULT_VEHTYPE;50.00;0.00;;;;;;;;
1.00;90.00;east;e1_0;15.10;0.00;10.00;DEFAULT_VEHTYPE;20.00;5.00;;;;;;;;
1.00;0.00;north;e2_0;9.10;0.00;4.00;DEFAULT_VEHTYPE;50.00;4.00;;;;;;;;
1.00;;;;;;;;;;225.00;e1;p0;0.0;0.00;1.41;1.00;1.00
2.00;90.00;east;e1_0;25.10;0.00;10.00;DEFAULT_VEHTYPE;30.00;5.00;;;;;;;;
2.00;;;;;;;;;;225.00;e1;p0;1.4;0.00;1.41;0.00;0.00
3.00;;;;;;;;;;;;;;;;;
"""


def test_sumo_fcd_xml_and_csv(tmp_path):
    (tmp_path / "fcd.xml").write_text(SUMO_XML)
    (tmp_path / "fcd.csv").write_text(SUMO_CSV)
    xml = dpgp.read_tracks(tmp_path / "fcd.xml")  # recognised by its extension and root
    csv = dpgp.read_tracks(tmp_path / "fcd.csv", preset="sumo")
    for df in (xml, csv):
        assert_tracks_table(df)
        assert len(df) == 7 and df["track"].nunique() == 3
        by = {(k, i): g for (k, i), g in df.groupby(["kind", "id"])}
        east, north, person = by[("vehicle", "east")], by[("vehicle", "north")], by[("person", "p0")]
        # angle: degrees clockwise from north. 90 = east (+x), 0 = north (+y), 225 = south-west
        assert np.allclose(east[["vx", "vy"]], [10.0, 0.0], atol=1e-12)
        assert np.allclose(north[["vx", "vy"]], [0.0, 4.0], atol=1e-12)
        assert np.allclose(person[["vx", "vy"]], [-1.0, -1.0], atol=1e-2)
        # ... and agree with the positions' own motion
        assert np.allclose(np.diff(east["x"]) / np.diff(east["t"]), east["vx"].iloc[1:])
    assert np.allclose(xml[["t", "x", "y", "vx", "vy"]].to_numpy(), csv[["t", "x", "y", "vx", "vy"]].to_numpy())


def test_sumo_rejects_other_xml(tmp_path):
    (tmp_path / "net.xml").write_text('<net version="1.9"><edge id="e1"/></net>')
    with pytest.raises(dpgp.DataFormatError, match="not SUMO FCD"):
        dpgp.read_tracks(tmp_path / "net.xml")
    (tmp_path / "broken.xml").write_text("<fcd-export><timestep time='0'><vehicle id='a'")
    with pytest.raises(dpgp.DataFormatError, match="XML"):
        dpgp.read_tracks(tmp_path / "broken.xml")


# --- generic tables ----------------------------------------------------------------------------


def _generic(n=20):
    rng = np.random.default_rng(1)
    return pd.DataFrame(
        {
            "vehicle": np.repeat(["a", "b", "c"], n),
            "time_s": np.tile(np.arange(n) * 0.2, 3),
            "px": rng.normal(size=3 * n),
            "py": rng.normal(size=3 * n),
            "lane": np.repeat([1, 2, 3], n),
        }
    )


def test_read_tracks_formats_agree(tmp_path):
    pytest.importorskip("pyarrow")
    src = _generic()
    kw = dict(id="vehicle", t="time_s", x="px", y="py")
    ref = dpgp.read_tracks(src, **kw)
    assert_tracks_table(ref)
    assert list(ref.columns) == ["track", "t", "x", "y", "vehicle", "lane"]
    src.to_csv(tmp_path / "a.csv", index=False)
    src.to_csv(tmp_path / "a.tsv", sep="\t", index=False)
    src.to_csv(tmp_path / "a.csv.gz", index=False)
    src.to_parquet(tmp_path / "a.parquet")
    import polars as pl

    for source in (
        tmp_path / "a.csv",
        tmp_path / "a.tsv",
        tmp_path / "a.csv.gz",
        tmp_path / "a.parquet",
        pl.from_pandas(src),
    ):
        got = dpgp.read_tracks(source, **kw)
        assert np.array_equal(got[["track", "t", "x", "y"]].to_numpy(), ref[["track", "t", "x", "y"]].to_numpy()), (
            source
        )


def test_read_tracks_finds_common_names_and_positions(tmp_path):
    df = pd.DataFrame(
        {"ID": [5, 5, 6], "Time": [0.0, 1.0, 0.5], "X": [0, 1, 2], "Y": [0, 0, 1], "VX": [1, 1, 0], "vy": [0, 0, 0]}
    )
    got = dpgp.read_tracks(df)
    assert list(got.columns[:6]) == ["track", "t", "x", "y", "vx", "vy"] and "ID" in got.columns
    path = tmp_path / "noheader.txt"
    path.write_text("0 1 0.0 0.0\n1 1 1.0 0.5\n0 2 3.0 3.0\n")
    got = dpgp.read_tracks(path, id=1, t=0, x=2, y=3)
    assert list(got["track"]) == [0, 0, 1] and list(got["x"]) == [0.0, 1.0, 3.0]


def test_read_tracks_sort_and_time_order(tmp_path):
    src = _generic().sample(frac=1.0, random_state=3)  # rows shuffled
    kw = dict(id="vehicle", t="time_s", x="px", y="py")
    with pytest.raises(dpgp.InvalidInputError, match="goes backwards inside track 'a'.*sort=True"):
        dpgp.read_tracks(src, **kw)
    got = dpgp.read_tracks(src, sort=True, **kw)
    assert np.array_equal(got[["t", "x"]].to_numpy(), dpgp.read_tracks(_generic(), **kw)[["t", "x"]].to_numpy())
    dup = pd.concat([_generic().iloc[:3], _generic().iloc[2:3]])
    with pytest.raises(dpgp.InvalidInputError, match="repeats"):
        dpgp.read_tracks(dup, **kw)
    # rows interleaved by time are fine: each track is still in time order
    inter = _generic().sort_values("time_s", kind="stable")
    assert np.array_equal(
        dpgp.read_tracks(inter, **kw)["x"].to_numpy(), dpgp.read_tracks(_generic(), **kw)["x"].to_numpy()
    )


def test_read_tracks_bad_input(tmp_path):
    src = _generic()
    with pytest.raises(dpgp.DataFormatError, match="'vehicel'.*did you mean 'vehicle'"):
        dpgp.read_tracks(src, id="vehicel", t="time_s", x="px", y="py")
    with pytest.raises(dpgp.DataFormatError, match="no column for 't'.*read_tracks\\(..., t='your_column'\\)"):
        dpgp.read_tracks(src.rename(columns={"vehicle": "id"}), x="px", y="py")
    with pytest.raises(dpgp.DataFormatError, match="both velocity columns"):
        dpgp.read_tracks(src, id="vehicle", t="time_s", x="px", y="py", vx="lane")
    nan = src.copy()
    nan.loc[4, "px"] = np.nan
    with pytest.raises(dpgp.InvalidInputError, match="'px' .* 1 missing .* row 4"):
        dpgp.read_tracks(nan, id="vehicle", t="time_s", x="px", y="py")
    text = src.assign(px=src["px"].astype(str))
    text.loc[2, "px"] = "north"
    with pytest.raises(dpgp.DataFormatError, match="'north' at row 2"):
        dpgp.read_tracks(text, id="vehicle", t="time_s", x="px", y="py")
    prose = tmp_path / "notes.txt"
    prose.write_text("Meeting notes\nwe talked about the weather and lunch\n")
    with pytest.raises(dpgp.DataFormatError):
        dpgp.read_tracks(prose)
    binary = tmp_path / "blob.csv"
    binary.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(dpgp.DataFormatError):
        dpgp.read_tracks(binary)
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(dpgp.DataFormatError, match="empty"):
        dpgp.read_tracks(tmp_path / "empty.csv")
    with pytest.raises(dpgp.DataFormatError, match="looks like an NGSIM file: read it with dpgp.read_ngsim"):
        dpgp.read_tracks(real("ngsim_peachtree_raw.csv"))
    with pytest.raises(dpgp.DataFormatError, match="already framed table .* dpgp.read_frames"):
        dpgp.read_tracks(real("ngsim_us101_frames.tsv"))
    with pytest.raises(dpgp.InvalidInputError, match="unknown preset"):
        dpgp.read_tracks(src, preset="argoverse")
    with pytest.raises(dpgp.InvalidInputError, match="time_scale"):
        dpgp.read_tracks(src, id="vehicle", t="time_s", x="px", y="py", time_scale=-1)
    with pytest.raises(dpgp.DataFormatError, match="path or a DataFrame"):
        dpgp.read_tracks([1, 2, 3])
    with pytest.raises(FileNotFoundError):
        dpgp.read_tracks(tmp_path / "nope.csv")
