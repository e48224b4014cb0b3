"""The sampler's settings cross the binding as one dict and are checked in one place, the core
(rust/core/src/gibbs.rs): names by its enums' FromStr, ranges and limits by Settings::validate
and check_threads. Python resolves "auto" and passes everything else through."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import dpgp
from dpgp import _core

ROOT = Path(__file__).resolve().parents[2]

#: What a user gives; the keys the data decide (params, basis, ...) may be left out.
GOOD = {
    "assignment": "gibbs",
    "proposal": "informed",
    "split_merge_pairs": "uniform",
    "fixed_length_scales": False,
    "alpha": None,
    "new_pattern_samples": 10,
    "seed": 0,
    "n_threads": None,
    "length_scale_fraction": 1.0,
    "pattern_moments": False,
    "split_merge": 0,
}


@pytest.mark.parametrize(
    "bad, message",
    [
        (dict(assignment="greedy"), "assignment must be one of 'gibbs', 'map'"),
        (dict(proposal="smart"), "proposal must be one of 'full', 'informed'"),
        (dict(split_merge_pairs="near"), "split_merge_pairs must be one of 'uniform', 'informed'"),
        (dict(likelihood="sparse"), "likelihood must be one of 'exact', 'hsgp'"),
        (dict(new_pattern_samples=0), "new_pattern_samples must be an integer in \\[1, 100000\\]"),
        (dict(new_pattern_samples=-1), "new_pattern_samples"),
        (dict(new_pattern_samples=2**64), "new_pattern_samples"),
        (dict(n_threads=0), "n_threads must be None or an integer in \\[1, 1024\\]"),
        (dict(n_threads=_core.MAX_THREADS + 1), "n_threads"),
        (dict(alpha=0.0), "alpha must be None"),
        (dict(alpha=True), "alpha must not be a bool"),
        (dict(length_scale_fraction="x"), "length_scale_fraction"),
        (dict(split_merge=_core.MAX_SPLIT_MERGE_MOVES + 1), "split_merge"),
        (dict(seed=1.5), "seed"),
        (dict(pattern_moments="yes"), "pattern_moments"),
        (dict(bogus=1), "unknown sampler setting"),
    ],
)
def test_the_core_rejects_a_bad_setting_with_the_typed_error(bad, message):
    with pytest.raises(dpgp.InvalidInputError, match=message):
        _core.check_settings({**GOOD, **bad})
    xy, offsets = np.zeros((2, 2)), np.array([0, 1, 2])
    with pytest.raises(dpgp.InvalidInputError, match=message):  # the sampler's own check, the same rule
        _core.Sampler(xy, xy, offsets, {**GOOD, **bad})


def test_good_settings_pass_and_the_limits_come_from_the_core():
    _core.check_settings(GOOD)
    _core.check_settings({**GOOD, "likelihood": "hsgp", "seed": -(2**70), "n_threads": _core.MAX_THREADS})
    assert (_core.MAX_THREADS, _core.MAX_NEW_PATTERN_SAMPLES) == (1024, 100_000)
    assert dpgp._arrays.ALPHA_RANGE == _core.ALPHA_RANGE


def test_fit_checks_the_settings_before_any_pilot(monkeypatch):
    frames = dpgp.datasets.synthetic("intersection", n_frames=30, seed=2)

    def no_pilot(*args, **kwargs):
        raise AssertionError("a pilot ran before the settings were checked")

    monkeypatch.setattr(dpgp.DPGP, "_pilot_fit", no_pilot)
    with pytest.raises(dpgp.InvalidInputError, match="proposal must be one of"):
        dpgp.DPGP(noise_var="pilot", proposal="smart", progress=False).fit(frames)


#: Each limit of a setting: how its value is spelt, and a word that marks a line as about it.
LIMITS = {
    "threads": (r"\b1_?024\b", r"thread"),
    "auxiliary patterns": (r"\b100_?000\b|\b1e5\b", r"new_pattern|auxiliar"),
    "split-merge moves": (r"\b1_?000_?000\b|\b1e6\b", r"split"),
    "alpha range": (r"\b1e-?100\b", r"alpha"),
}


@pytest.mark.parametrize("limit", LIMITS)
def test_each_limit_is_written_once(limit):
    """The rule of issue 19: a setting's limit is a literal in one line of the code base, the
    core's constant; Python reads it from dpgp._core if it needs it."""
    value, topic = LIMITS[limit]
    files = [*ROOT.glob("python/dpgp/**/*.py"), *ROOT.glob("python/dpgp/**/*.pyi"), *ROOT.glob("rust/*/src/**/*.rs")]
    hits = [
        f"{path.relative_to(ROOT)}: {line.strip()}"
        for path in files
        if "tests" not in path.relative_to(ROOT).parts  # tests state the limits they check
        for line in path.read_text().splitlines()
        if re.search(value, line) and re.search(topic, line, re.IGNORECASE)
    ]
    assert len(hits) == 1 and hits[0].startswith("rust/core/src/gibbs.rs"), hits
