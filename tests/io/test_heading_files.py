"""Fits over heading (DPGP(inputs="position+heading"), issue 34) in model files, posterior draws
and checkpoints: a loaded model scores as the saved one, averaged scores use each draw's own
heading length scales (against a hand loop over the draws with the exact GP), a resumed chain is
bitwise the uninterrupted one; damaged or inconsistent files are ModelFileErrors."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.special import logsumexp

import dpgp
import dpgp.io
from dpgp.exceptions import ModelFileError
from dpgp.gp import exact
from dpgp.gp.draws import used
from dpgp.model.estimator import HEADING_PRIOR

from heading_roads import two_way_road as road_tracks
from model_files import _rewrite, _rewrite_metadata

HEADED = "position+heading"
# A small noise variance: the two-way road splits into several patterns, whose number and heading
# length scales change from draw to draw.
SETTINGS = dict(inputs=HEADED, seed=3, progress=False, noise_var=(0.02, 0.02), posterior_draws=10)


def two_way_road(n_vehicles: int = 24, seed: int = 0) -> dpgp.Frames:
    """The two-way road of :mod:`heading_roads`, framed with previous headings."""
    frames = dpgp.make_frames(road_tracks(n_vehicles, seed), dt=1.0)
    assert frames.prev_heading is not None and np.isnan(frames.prev_heading).any()  # unknown headings too
    return frames


@pytest.fixture(scope="module")
def road() -> tuple[dpgp.Frames, dpgp.Frames]:
    frames = two_way_road()
    n = len(frames)
    return frames[: int(0.7 * n)], frames[int(0.7 * n) :]


@pytest.fixture(scope="module", params=["exact", "hsgp"])
def saved(request, road, tmp_path_factory) -> tuple[dpgp.DPGP, Path]:
    train, _ = road
    model = dpgp.DPGP(**SETTINGS, iterations=10, likelihood=request.param, n_basis=(12, 4), store_labels=True)
    model.fit(train)
    path = tmp_path_factory.mktemp("heading") / f"{request.param}.npz"
    model.save(path)
    return model, path


def test_a_loaded_heading_model_scores_as_the_saved_one(saved, road):
    model, path = saved
    _, test = road
    back = dpgp.DPGP.load(path)
    assert back.inputs == HEADED and back.likelihood_ == model.likelihood_
    assert model.n_patterns_ >= 2 and len(np.unique(model.heading_scales_)) == model.n_patterns_
    for name in ("labels_", "length_scales_", "heading_scales_", "pattern_ids_", "label_trace_"):
        np.testing.assert_array_equal(getattr(back, name), getattr(model, name), err_msg=name)
    assert back.alpha_ == model.alpha_ and back.log_joint_ == model.log_joint_
    assert back.engine_info()["heading"] == model.engine_info()["heading"]
    assert model.engine_info()["heading"]["harmonics"] == (None if model.likelihood_ == "exact" else 3)
    # hsgp's heading blocks on min(m, max(ceil(m / 4), 10)) position functions per axis
    assert model.engine_info()["heading"]["heading_counts"] == (None if model.likelihood_ == "exact" else [10, 4])
    close = dict(rtol=1e-10, atol=1e-10)
    for average in (False, True):
        for positions in (False, True):
            np.testing.assert_allclose(
                back.score_samples(test, positions=positions, average=average),
                model.score_samples(test, positions=positions, average=average), **close,
            )  # fmt: skip
        np.testing.assert_allclose(
            back.predict_proba(test, average=average), model.predict_proba(test, average=average), **close
        )
    np.testing.assert_array_equal(back.predict(test), model.predict(test))
    np.testing.assert_allclose(back.training_log_likelihoods(), model.training_log_likelihoods(), **close)
    # the draws and their heading length scales survive the file
    assert back.draws_.sweeps == model.draws_.sweeps and len(model.draws_) >= 3
    for a, b in zip(back.draws_.heading_scales, model.draws_.heading_scales):
        np.testing.assert_array_equal(a, b)


def test_the_file_holds_the_heading_members(saved):
    model, path = saved
    with np.load(path, allow_pickle=False) as npz:
        meta = json.loads(str(npz["metadata"]))
        np.testing.assert_array_equal(npz["heading_scales"], model.heading_scales_)
        assert npz["draw_heading_scales"].shape == (int(npz["draw_n_patterns"].sum()),)
        assert "frame_prev_heading" in npz.files
    assert meta["settings"]["inputs"] == HEADED and meta["format_version"] == 2
    assert meta["engine"]["heading"]["prior"] == list(HEADING_PRIOR)


def _without(*names):
    return lambda name, a: None if name in names else a


def _scaled(member, factor):
    return lambda name, a: a * factor if name == member else a


@pytest.mark.parametrize(
    "change, match",
    [
        (_without("frame_prev_v", "frame_prev_heading"), "previous headings"),
        (_without("heading_scales"), "no heading length scales"),
        (_scaled("heading_scales", -1.0), "heading_scales must lie in"),
        (_scaled("heading_scales", np.nan), "heading_scales must lie in"),
        (lambda name, a: a[:-1] if name == "heading_scales" else a, "one heading length scale per pattern"),
        (_without("draw_heading_scales"), "heading length scales exactly when the model does"),
        (_scaled("draw_heading_scales", 0.0), "draws' heading length scales must lie in"),
    ],
    ids=["no-frame-headings", "no-scales", "negative", "nan", "short", "no-draw-scales", "zero-draw-scales"],
)
def test_damaged_heading_members_are_a_model_file_error(saved, tmp_path, change, match):
    _, path = saved
    bad = tmp_path / "bad.npz"
    _rewrite(path, bad, change)
    with pytest.raises(ModelFileError, match=match):
        dpgp.DPGP.load(bad)


@pytest.mark.parametrize(
    "edit, match",
    [
        # a file from before the engine's inputs entry
        (
            lambda m: (m["settings"].update(inputs="position"), m["engine"].pop("inputs")),
            "heading length scales but its fields are over",
        ),
        (lambda m: m["settings"].update(inputs="position"), "settings give inputs='position' but the engine ran"),
        (lambda m: m["engine"].update(inputs="heading"), "not a fields' input"),
        # inputs="auto" needs the input it resolved to
        (lambda m: (m["settings"].update(inputs="auto"), m["engine"].pop("inputs")), "not a fields' input"),
        (lambda m: m["engine"]["heading"].update(prior=[6.0, -1.0]), "heading entry"),
        # exact: no harmonics; hsgp: a count
        (
            lambda m: m["engine"]["heading"].update(harmonics=2 if m["engine"]["likelihood"] == "exact" else "3"),
            "heading entry",
        ),
        # exact: no heading counts; hsgp: two positive counts or none
        (
            lambda m: m["engine"]["heading"].update(
                heading_counts=[2, 1] if m["engine"]["likelihood"] == "exact" else [0, 1]
            ),
            "heading entry",
        ),
    ],
    ids=[
        "position-inputs",
        "settings-disagree",
        "unknown-inputs",
        "auto-unresolved",
        "bad-prior",
        "bad-harmonics",
        "bad-heading-counts",
    ],
)
def test_inconsistent_heading_metadata_is_a_model_file_error(saved, tmp_path, edit, match):
    _, path = saved
    bad = tmp_path / "bad.npz"
    _rewrite_metadata(path, bad, edit)
    with pytest.raises(ModelFileError, match=match):
        dpgp.DPGP.load(bad)


def test_hsgp_heading_files_without_heading_counts_load_as_the_full_product(saved, road, tmp_path):
    """Files written before the heading blocks had fewer position functions than the constant's
    hold no ``heading_counts``: they were fitted with every position function in every block, and
    load so (not with today's stride, which would score their patterns under another kernel)."""
    model, path = saved
    if model.likelihood_ == "exact":
        pytest.skip("the exact engine has no basis")
    _rewrite_metadata(path, tmp_path / "old.npz", lambda m: m["engine"]["heading"].pop("heading_counts"))
    old = dpgp.DPGP.load(tmp_path / "old.npz")
    assert old.engine_info()["heading"]["heading_counts"] is None
    _, test = road
    a, b = old.score_samples(test, positions=False), model.score_samples(test, positions=False)
    assert np.all(np.isfinite(a)) and np.max(np.abs(a - b)) > 1e-6  # another basis: other densities


def test_position_files_without_inputs_load_as_fields_over_position(road, tmp_path):
    train, test = road
    model = dpgp.DPGP(iterations=3, seed=1, progress=False, likelihood="exact").fit(train)
    model.save(tmp_path / "m.npz")
    with np.load(tmp_path / "m.npz", allow_pickle=False) as npz:
        assert "heading_scales" not in npz.files and "draw_heading_scales" not in npz.files
        assert "heading" not in json.loads(str(npz["metadata"]))["engine"]
    _rewrite_metadata(
        tmp_path / "m.npz", tmp_path / "old.npz", lambda m: m["settings"].pop("inputs")
    )  # before issue 34
    old = dpgp.DPGP.load(tmp_path / "old.npz")
    assert old.inputs == "position" and not hasattr(old, "heading_scales_")
    np.testing.assert_array_equal(old.score_samples(test, average=True), model.score_samples(test, average=True))
    # heading length scales added to a file of fields over position
    with np.load(tmp_path / "m.npz", allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    np.savez(tmp_path / "bad.npz", **arrays, heading_scales=np.ones(model.n_patterns_))
    with pytest.raises(ModelFileError, match="heading length scales but its fields are over 'position'"):
        dpgp.DPGP.load(tmp_path / "bad.npz")


# --- posterior draws ------------------------------------------------------------------------------


def _hand_averaged(model, train, test, new, heading=lambda wh: wh):
    """Posterior-averaged log density and pattern probabilities by a loop over the states (kept
    draws after burn-in, then the final state): each pattern's exact GP predictive with that
    state's length scales and heading length scale ``heading(w_h)``, the frames' own headings.
    ``new``: each test frame's new-pattern log density (the same in every state)."""
    d, n = model.draws_, len(train)
    states = [(d.labels[i].astype(np.int64), d.length_scales[i], d.alpha[i], d.heading_scales[i])
              for i in used(d, model.n_iter_)]  # fmt: skip
    states.append((model.labels_, model.length_scales_, model.alpha_, model.heading_scales_))
    p = model.params_
    blocks = []
    for labels, ls, alpha, wh in states:
        terms = np.empty((len(test), len(ls) + 1))
        for k in range(len(ls)):
            members = train[np.flatnonzero(labels == k)]
            gp = exact.GPParams(tuple(ls[k]), p.signal_var, p.noise_var, p.mean, heading_scale=heading(wh[k]))
            for i, f in enumerate(test):
                lp = exact.log_predictive(members.xy, members.v, f.xy, f.v, gp, members.prev_heading, f.prev_heading)
                terms[i, k] = np.log(len(members) / (n + alpha)) + lp
        terms[:, -1] = np.log(alpha / (n + alpha)) + new
        overlap = np.zeros((len(ls) + 1, model.n_patterns_ + 1))
        for j in range(len(ls)):
            overlap[j, :-1] = np.bincount(model.labels_[labels == j], minlength=model.n_patterns_) / np.sum(labels == j)
        overlap[-1, -1] = 1.0
        blocks.append((terms, overlap))
    density = logsumexp([logsumexp(t, axis=1) for t, _ in blocks], axis=0) - np.log(len(blocks))
    joint = logsumexp(np.concatenate([t for t, _ in blocks], axis=1), axis=1)
    return density, sum(np.exp(t - joint[:, None]) @ o for t, o in blocks)


def test_averaged_heading_scores_use_each_draws_heading_length_scales(road, tmp_path):
    train, test = road
    model = dpgp.DPGP(**SETTINGS, iterations=10, likelihood="exact").fit(train)
    d = model.draws_
    kept = [d.heading_scales[i] for i in used(d, model.n_iter_)]
    assert len(kept) >= 3 and len({tuple(w) for w in kept} | {tuple(model.heading_scales_)}) == len(kept) + 1
    _, new = model._fitted().log_scores(test)  # Algorithm 8's auxiliary prior draws: the frame's and the seed's
    want_density, want_proba = _hand_averaged(model, train, test, new)
    got = model.score_samples(test, positions=False, average=True)
    np.testing.assert_allclose(got, want_density, rtol=1e-9)
    np.testing.assert_allclose(model.predict_proba(test, average=True), want_proba, rtol=1e-7, atol=1e-12)
    # the test would catch draws scored over position alone (w_h = ∞)
    blind, _ = _hand_averaged(model, train, test, new, heading=lambda wh: np.inf)
    assert np.max(np.abs(blind - got)) > 1e-3
    assert np.max(np.abs(got - model.score_samples(test, positions=False))) > 1e-6
    # and through a model file
    model.save(tmp_path / "m.npz")
    back = dpgp.DPGP.load(tmp_path / "m.npz")
    np.testing.assert_allclose(back.score_samples(test, positions=False, average=True), want_density, rtol=1e-9)


# --- checkpoints ------------------------------------------------------------------------------------


class Recording(dpgp.DPGP):
    """A fit that keeps a copy of every checkpoint it writes."""

    def _write_checkpoint(self, traces):  # noqa: ANN001
        super()._write_checkpoint(traces)
        copies = self.__dict__.setdefault("copies", [])
        copy = Path(f"{self.checkpoint}.{len(copies)}")
        shutil.copy(self.checkpoint, copy)
        copies.append(copy)


def differences(a: dpgp.DPGP, b: dpgp.DPGP) -> list[str]:
    """What differs between two fits over heading, bit for bit (wall-clock seconds aside)."""
    names = ("labels_", "length_scales_", "heading_scales_", "label_trace_")
    out = [n for n in names if not np.array_equal(getattr(a, n), getattr(b, n))]
    out += [n for n in ("alpha_", "n_iter_", "converged_", "log_joint_") if getattr(a, n) != getattr(b, n)]
    strip = lambda h: {k: v for k, v in h.items() if k != "seconds"}  # noqa: E731
    out += ["history_"] if strip(a.history_) != strip(b.history_) else []
    same_draws = a.draws_.sweeps == b.draws_.sweeps and all(
        np.array_equal(x, y) for x, y in zip(a.draws_.heading_scales, b.draws_.heading_scales)
    )
    return out + ([] if same_draws else ["draws_"])


@pytest.mark.parametrize("likelihood", ["exact", "hsgp"])
def test_a_heading_fit_resumes_from_every_checkpoint_to_the_uninterrupted_fit(road, tmp_path, likelihood):
    train, _ = road
    settings = dict(SETTINGS, iterations=7, checkpoint_every=2, store_labels=True, likelihood=likelihood,
                    n_basis=(12, 4))  # fmt: skip
    fit = Recording(**settings, checkpoint=str(tmp_path / "fit.ckpt")).fit(train)
    assert len(fit.copies) >= 3
    for copy in fit.copies:
        with np.load(copy, allow_pickle=False) as npz:
            assert "resume_heading_scales" in npz.files
        resumed = dpgp.DPGP.resume(copy)
        assert differences(fit, resumed) == [], copy.name
    assert differences(fit, dpgp.DPGP(**settings).fit(train)) == []  # checkpoints change nothing
    # the chain resumes from the stored w_h: other ones part it (the checkpoint written at its
    # resume point holds the same state as its model)
    edited = tmp_path / "edited.npz"  # np.savez names it .npz
    _rewrite(
        fit.copies[1], edited, lambda name, a: a * 1.5 if name in ("heading_scales", "resume_heading_scales") else a
    )
    assert "heading_scales_" in differences(fit, dpgp.DPGP.resume(edited))


def test_a_heading_checkpoint_without_resume_heading_scales_is_refused(road, tmp_path):
    train, _ = road
    dpgp.DPGP(**SETTINGS, iterations=3, checkpoint_every=2, likelihood="exact", checkpoint=str(tmp_path / "c")).fit(
        train
    )
    _rewrite(tmp_path / "c", tmp_path / "bad.npz", _without("resume_heading_scales"))
    with pytest.raises(ModelFileError, match="resume_heading_scales"):
        dpgp.DPGP.resume(tmp_path / "bad.npz")
    with pytest.raises(ModelFileError, match="resume_heading_scales"):
        dpgp.DPGP.load(tmp_path / "bad.npz")
