"""What the command line did on its own is in the API now: DPGP.summary (dpgp info),
dpgp.plot.write_figures (dpgp plot), dpgp.read (dpgp fit/evaluate --format auto, tests/data/test_read.py)."""

from __future__ import annotations

import pytest

import dpgp
from dpgp import cli


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    frames = dpgp.datasets.synthetic("intersection", n_frames=30, seed=0)
    model = dpgp.DPGP(iterations=4, seed=1, progress=False, noise_var=0.49).fit(frames)
    path = tmp_path_factory.mktemp("m") / "m.npz"
    model.save(path)
    return path


def test_info_prints_the_file_line_then_the_summary(model_file, capsys):
    model = dpgp.DPGP.load(model_file)
    text = model.summary(top=2)
    assert text.startswith("training data: 30 frames") and f"patterns: {model.n_patterns_};" in text
    assert "largest 2 patterns" in text and "settings: " in text and "resolved: noise variance" in text
    assert cli.main(["info", str(model_file), "--top", "2"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert (
        out[0].startswith(f"{model_file}: dpgp-model format")
        and "\n".join(out[1:]) == text + "\n" + model.transitions_.summary()
    )
    with pytest.raises(dpgp.NotFittedError):
        dpgp.DPGP().summary()


def test_write_figures_writes_what_dpgp_plot_writes(model_file, tmp_path, capsys):
    model = dpgp.DPGP.load(model_file)
    paths = dpgp.plot.write_figures(
        model, tmp_path / "api", kinds=("weights", "field", "simulation"), n_patterns=2, steps=3
    )
    names = sorted(p.name for p in paths)
    fields = [f"field_{k}.png" for k in range(min(2, model.n_patterns_))]
    assert names == sorted(["weights.png", "simulation.png", *fields])
    assert all(p.stat().st_size > 0 for p in paths)
    cli.main(
        [
            "plot",
            str(model_file),
            "--out",
            str(tmp_path / "cli"),
            "--kind",
            "weights",
            "field",
            "simulation",
            "--patterns",
            "2",
            "--steps",
            "3",
        ]
    )
    assert sorted(p.name for p in (tmp_path / "cli").iterdir()) == names
    with pytest.raises(dpgp.InvalidInputError, match="unknown figure kinds"):
        dpgp.plot.write_figures(model, tmp_path, kinds=("heatmap",))
