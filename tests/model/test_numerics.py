"""Numerics that hold on real exports (issue 11, item 3): large coordinate offsets, duplicate
positions, other units, frames of one vehicle and a single frame. Each case fits or fails with
a typed error that says what to fix; each test says what the case now does.

Where the offsets go: the engine sees positions only through differences (kernel distances
``p - q``, HSGP arguments ``u - c + L``, cell and ψ-bin indices ``(p - origin) / size``), and
each difference of two nearby large coordinates is exact (Sterbenz). So an offset loses nothing
beyond the rounding of the input itself: positions on a binary grid give bitwise the same fit
after an offset. Recorded decimal positions (NGSIM: 0.001 ft, 0.1 ft) are rounded differently
after one (by up to 5e-10 ft at 6e6 ft), which moves every result by about that much, except
where a grid edge falls exactly on recorded positions: there rounding alone picked the bin, and
an offset or a change of units could pick another. ψ (:mod:`dpgp.distributions`) now counts a
position within 1e-6 of a bin below an edge as on it; the informed proposal's cell grid
(rust/core/src/proposal.rs) now starts an irrational fraction of a cell below the data, so that
its edges miss any decimal grid.
"""

from __future__ import annotations

import numpy as np
import pytest

import dpgp
from dpgp.evaluate.metrics import adjusted_rand_index
from dpgp.generate.distributions import EmpiricalDistributions
from dpgp.model import MIN_NOISE_RATIO

#: NGSIM's Global_X / Global_Y are state-plane feet, about 6e6 and 2e6.
OFFSET = (6.0e6, 2.0e6)
FEET = 0.3048
#: Fixed settings (US-101 is in feet: the paper's) where a test is not about the defaults.
PAPER = dict(noise_var=1.0, length_scale_prior=(10.0, 1.0))
#: A small fixed basis for hsgp keeps these tests fast (the sizing rule is tested in test_hsgp).
ENGINES = {"exact": dict(likelihood="exact"), "hsgp": dict(likelihood="hsgp", n_basis=(10, 20))}


def transformed(frames: dpgp.Frames, shift=(0.0, 0.0), scale: float = 1.0) -> dpgp.Frames:
    """The same frames with positions ``scale * xy + shift`` and velocities ``scale * v``."""
    ids = np.repeat(np.arange(len(frames)), frames.sizes)
    xy = frames.xy * scale + np.asarray(shift, dtype=float)
    v = frames.v * scale
    return dpgp.Frames.from_arrays(ids, xy[:, 0], xy[:, 1], v[:, 0], v[:, 1])


def from_rows(rows: list[np.ndarray]) -> dpgp.Frames:
    """Frames from a list of ``(l, 4)`` arrays of ``x, y, vx, vy``."""
    ids = np.concatenate([np.full(len(r), i) for i, r in enumerate(rows)])
    a = np.concatenate(rows)
    return dpgp.Frames.from_arrays(ids, a[:, 0], a[:, 1], a[:, 2], a[:, 3])


def rows_of(frames: dpgp.Frames) -> list[np.ndarray]:
    return [np.column_stack([f.xy, f.v]) for f in frames]


def fit(frames: dpgp.Frames, **settings) -> dpgp.DPGP:
    return dpgp.DPGP(**{"iterations": 3, "seed": 1, "progress": False, **settings}).fit(frames)


def assert_usable(model: dpgp.DPGP, frames: dpgp.Frames) -> None:
    """Every way of using the fit returns finite values."""
    assert np.isfinite(model.log_joint_)
    assert np.all(np.isfinite(model.score_samples(frames)))
    assert np.all(np.isfinite(model.predict_proba(frames)))
    assert model.predict(frames).shape == (len(frames),)
    for k in range(model.n_patterns_):
        mean, var = model.velocity_field(k, frames.xy[:20])
        assert np.all(np.isfinite(mean)) and np.all(np.isfinite(var)) and np.all(var >= 0)
    sim = model.simulate(0, steps=5)
    assert np.all(np.isfinite(sim.positions)) and np.all(np.isfinite(sim.velocities))


@pytest.fixture(scope="module")
def us101(us101_path) -> dpgp.Frames:
    return dpgp.read_frames(us101_path)[:150]


@pytest.fixture(scope="module")
def synthetic() -> dpgp.Frames:
    return dpgp.datasets.synthetic("intersection", 60, seed=2)


# --- 1. large offsets ---------------------------------------------------------------------------


def assert_same_fit(
    a: dpgp.DPGP, fa: dpgp.Frames, b: dpgp.DPGP, fb: dpgp.Frames, shift, rtol: float, atol: float
) -> None:
    """``b`` (fitted to ``fa`` shifted by ``shift``, as ``fb``) is ``a`` up to the tolerances."""
    np.testing.assert_array_equal(b.labels_, a.labels_)
    np.testing.assert_allclose(b.length_scales_, a.length_scales_, rtol=rtol)
    np.testing.assert_allclose(b.alpha_, a.alpha_, rtol=rtol)
    np.testing.assert_allclose(b.log_joint_, a.log_joint_, rtol=rtol)
    np.testing.assert_allclose(b.score_samples(fb), a.score_samples(fa), rtol=rtol, atol=atol)
    np.testing.assert_array_equal(b.predict(fb), a.predict(fa))
    for k in range(a.n_patterns_):
        for got, want in zip(b.velocity_field(k, fa.xy + shift), a.velocity_field(k, fa.xy)):
            np.testing.assert_allclose(got, want, rtol=rtol, atol=atol)
    # Euler steps at 6e6 ft round each position to ~1e-9 ft
    sa, sb = a.simulate(0, steps=10), b.simulate(0, steps=10)
    np.testing.assert_allclose(sb.positions - shift, sa.positions, atol=1e-6)


@pytest.mark.parametrize("proposal", ["full", "informed"])
@pytest.mark.parametrize("likelihood", ["exact", "hsgp"])
def test_an_offset_that_rounds_nothing_changes_nothing(us101, likelihood, proposal):
    """Now (and before): US-101 positions on a 1/1024-ft grid, shifted by NGSIM's state-plane
    offset (exact in binary), give bitwise the same labels, length scales, α, log joint, scores,
    predictions and velocity fields: no step of the fit depends on where the origin is."""
    grid = from_rows([np.column_stack([np.round(f.xy * 1024) / 1024, f.v]) for f in us101[:100]])
    shifted = transformed(grid, OFFSET)
    settings = dict(proposal=proposal, **ENGINES[likelihood], **PAPER)
    assert_same_fit(fit(grid, **settings), grid, fit(shifted, **settings), shifted, OFFSET, rtol=0, atol=0)


@pytest.mark.parametrize("proposal", ["full", "informed"])
@pytest.mark.parametrize("likelihood", ["exact", "hsgp"])
def test_ngsim_state_plane_offset_on_us101(us101, likelihood, proposal):
    """Recorded US-101 positions shifted to state-plane feet: the same labels and, up to the
    input's own rounding (5e-10 ft), the same numbers. Before: ψ's bins held the positions on
    their edges (3 here) by rounding, and score_samples differed in their frames; with proposal
    "informed", the cell grid did the same and chains could part (next test)."""
    shifted = transformed(us101, OFFSET)
    settings = dict(proposal=proposal, **ENGINES[likelihood], **PAPER)
    a, b = fit(us101, **settings), fit(shifted, **settings)
    assert_same_fit(a, us101, b, shifted, OFFSET, rtol=1e-7, atol=1e-6)


@pytest.mark.parametrize("units", ["state-plane offset", "millimetres"])
def test_informed_chains_on_us101_do_not_depend_on_offset_or_units(us101, units):
    """Proposal "informed" on recorded US-101 positions after an offset or in millimetres: the
    same partition for each of four seeds. Before the cell grid's offset (c9ec827), two of these
    four short chains parted from the unshifted ones."""
    shift, scale = (OFFSET, 1.0) if units == "state-plane offset" else ((0.0, 0.0), 1000.0)
    other = transformed(us101, shift, scale)
    scaled = dict(noise_var=scale**2, length_scale_prior=(10.0, scale))
    for seed in range(4):
        a = fit(us101, seed=seed, proposal="informed", **PAPER)
        b = fit(other, seed=seed, proposal="informed", **scaled)
        np.testing.assert_array_equal(b.labels_, a.labels_, err_msg=f"seed {seed}")


@pytest.mark.parametrize("proposal", ["full", "informed"])
@pytest.mark.parametrize("likelihood", ["exact", "hsgp"])
def test_state_plane_offset_on_synthetic_data(synthetic, likelihood, proposal):
    """Now and before: synthetic positions (no decimal grid) shifted by the state-plane offset
    give the same labels and the same numbers up to rounding, with either proposal."""
    shifted = transformed(synthetic, OFFSET)
    settings = dict(proposal=proposal, noise_var=1.0, **ENGINES[likelihood])
    a, b = fit(synthetic, **settings), fit(shifted, **settings)
    assert_same_fit(a, synthetic, b, shifted, OFFSET, rtol=1e-7, atol=1e-6)


def test_the_defaults_do_not_depend_on_offset(synthetic):
    """Now and before: the noise pilot and the length-scale prior see only differences of
    positions, so the default settings resolve to the same values after the offset, and the fit
    with them is the same."""
    shifted = transformed(synthetic, OFFSET)
    a, b = fit(synthetic, proposal="full"), fit(shifted, proposal="full")
    np.testing.assert_allclose(b.noise_var_, a.noise_var_, rtol=1e-9)
    np.testing.assert_allclose(b.length_scale_prior_, a.length_scale_prior_, rtol=1e-9)
    assert_same_fit(a, synthetic, b, shifted, OFFSET, rtol=1e-7, atol=1e-6)


def test_position_bins_do_not_depend_on_offset_or_units(us101_path):
    """ψ (the model's 20 x 20 bins) of US-101's first 200 frames, whose recorded positions fall on
    bin edges: the same histogram in feet, metres, millimetres and kilometres and after the
    state-plane offset. Before: 24 of the 3,272 positions changed bins after the offset, 23 in
    millimetres, 3 to 9 in the other cases."""
    feet = dpgp.read_frames(us101_path)[:200]
    metres = transformed(feet, scale=FEET)
    for base, shift, scale in [(feet, OFFSET, 1.0), (feet, (0.0, 0.0), 1000.0), (feet, (0.0, 0.0), 0.001),
                               (metres, (0.0, 0.0), 1000.0), (metres, (0.0, 0.0), 0.001), (metres, OFFSET, 1.0)]:  # fmt: skip
        ref = EmpiricalDistributions.from_frames(base, bins=(20, 20))
        other = EmpiricalDistributions.from_frames(transformed(base, shift, scale), bins=(20, 20))
        np.testing.assert_array_equal(other.position_hist, ref.position_hist)


# --- 2. duplicate positions ---------------------------------------------------------------------


def duplicated_vehicle(frames: dpgp.Frames) -> dpgp.Frames:
    """Every frame with its first vehicle twice (two vehicles at one point)."""
    return from_rows([np.vstack([r, r[:1]]) for r in rows_of(frames)])


def every_vehicle_twice(frames: dpgp.Frames) -> dpgp.Frames:
    """Every vehicle twice (the median nearest-vehicle distance, which sets the default
    length-scale prior, is then 0)."""
    return from_rows([np.vstack([r, r]) for r in rows_of(frames)])


def repeated_frame(frames: dpgp.Frames) -> dpgp.Frames:
    """20 frames and then the first one 30 more times (each of its positions 31 times)."""
    rows = rows_of(frames)
    return from_rows(rows[:20] + [rows[0]] * 30)


@pytest.mark.parametrize("make", [duplicated_vehicle, every_vehicle_twice, repeated_frame])
@pytest.mark.parametrize("likelihood", ["exact", "hsgp"])
def test_duplicate_positions_fit_with_the_smallest_noise(us101, make, likelihood):
    """Now and before: duplicates fit, and every result is finite, with the smallest noise a fit
    accepts (MIN_NOISE_RATIO of the signal variance): the noise keeps σ² R + σ_n² I positive
    definite although R is singular."""
    frames = make(us101[:40])
    model = fit(frames, likelihood=likelihood, noise_var=MIN_NOISE_RATIO * frames.v.var(axis=0), proposal="full")
    assert_usable(model, frames)


@pytest.mark.parametrize("make", [duplicated_vehicle, repeated_frame])
def test_duplicate_positions_fit_with_the_default_noise(us101, make):
    """Now and before: with the default settings too (the noise pilot fits duplicates as well)."""
    frames = make(us101[:40])
    assert_usable(fit(frames, proposal="full"), frames)


def test_a_noise_too_small_for_duplicates_is_refused_up_front(us101):
    """Now: noise_var below MIN_NOISE_RATIO of the signal variance is an InvalidInputError that
    names the least accepted value, before sampling. Before: it fitted until a duplicated
    position came up, then stopped with NotPositiveDefiniteError (from about 1e-16 of the signal
    variance; from 1e-14 with a frame repeated 150 times)."""
    frames = repeated_frame(us101[:40])
    for tiny in (1e-16, (1.0, 1e-13), 0.5e-10 * frames.v.var(axis=0)):
        with pytest.raises(dpgp.InvalidInputError, match="noise_var .* at least"):
            fit(frames, noise_var=tiny)


# --- 3. millimetres and kilometres --------------------------------------------------------------


UNITS = {"metres": 1.0, "millimetres": 1000.0, "kilometres": 0.001}


@pytest.fixture(scope="module")
def unit_fits(us101):
    """US-101's first 60 frames in metres, millimetres and kilometres: (frames, fit with the
    default settings and proposal "full")."""
    out = {}
    for name, c in UNITS.items():
        frames = transformed(us101[:60], scale=FEET * c)
        out[name] = (frames, fit(frames, likelihood="exact", proposal="full"))
    return out


@pytest.mark.parametrize("units", ["millimetres", "kilometres"])
def test_millimetres_and_kilometres_give_the_metres_fit(unit_fits, units):
    """Default settings, proposal "full": the same partition as in metres (ARI 1.0; ≥ 0.95
    required), the resolved defaults and the length scales scaled, and log densities equal up to
    the Jacobian: −2 log c per vehicle for its velocity, as much again for its position (ψ is a
    density per unit area).
    Before: the same on these frames; on others ψ's bins held positions on their edges by
    rounding (on 200 frames, score_samples up to 0.6 nats per frame apart; see the ψ test)."""
    metres, ref = unit_fits["metres"]
    frames, model = unit_fits[units]
    c = UNITS[units]
    assert adjusted_rand_index(ref.labels_, model.labels_) >= 0.95
    np.testing.assert_array_equal(model.labels_, ref.labels_)
    np.testing.assert_allclose(model.noise_var_, np.multiply(ref.noise_var_, c**2), rtol=1e-9)
    np.testing.assert_allclose(model.length_scale_prior_[1], ref.length_scale_prior_[1] * c, rtol=1e-9)
    np.testing.assert_allclose(model.length_scales_, ref.length_scales_ * c, rtol=1e-6)
    log_c, sizes = np.log(c), frames.sizes
    np.testing.assert_allclose(
        model.score_samples(frames, positions=False),
        ref.score_samples(metres, positions=False) - 2 * sizes * log_c,
        atol=1e-6,
    )
    np.testing.assert_allclose(model.score_samples(frames), ref.score_samples(metres) - 4 * sizes * log_c, atol=1e-6)
    # the log joint also holds the densities of two length scales per pattern
    jacobian = -(2 * frames.n_points + 2 * model.n_patterns_) * log_c
    np.testing.assert_allclose(model.log_joint_, ref.log_joint_ + jacobian, rtol=1e-9)
    mean, var = model.velocity_field(0, frames.xy[:20])
    ref_mean, ref_var = ref.velocity_field(0, metres.xy[:20])
    np.testing.assert_allclose(mean, ref_mean * c, rtol=1e-6)
    np.testing.assert_allclose(var, ref_var * c**2, rtol=1e-6)


@pytest.mark.parametrize("units", ["millimetres", "kilometres"])
def test_millimetres_and_kilometres_with_the_informed_proposal(unit_fits, units):
    """Proposal "informed" (the default), with the defaults the "full" fits resolved (the noise
    pilot always runs "full"): the same partition as in metres. Before the cell grid's offset
    (c9ec827): ARI 0.98 against metres in millimetres on 200 frames."""
    fits = {}
    for name in ("metres", units):
        frames, full = unit_fits[name]
        fits[name] = fit(frames, likelihood="exact", proposal="informed", noise_var=full.noise_var_,
                         length_scale_prior=full.length_scale_prior_)  # fmt: skip
    assert adjusted_rand_index(fits["metres"].labels_, fits[units].labels_) >= 0.95
    np.testing.assert_array_equal(fits[units].labels_, fits["metres"].labels_)


def test_hsgp_in_millimetres(unit_fits):
    """The reduced-rank model in millimetres, with the defaults resolved above: the basis box
    scales with the data, its counts stay, and the partition is the one in metres."""
    fits = {}
    for name in ("metres", "millimetres"):
        frames, full = unit_fits[name]
        fits[name] = fit(frames, likelihood="hsgp", proposal="full", noise_var=full.noise_var_,
                         length_scale_prior=full.length_scale_prior_)  # fmt: skip
    a, b = fits["metres"], fits["millimetres"]
    assert adjusted_rand_index(a.labels_, b.labels_) >= 0.95
    assert b.basis_.counts == a.basis_.counts
    np.testing.assert_allclose(b.basis_.half_widths, np.multiply(a.basis_.half_widths, 1000.0), rtol=1e-9)
    np.testing.assert_allclose(b.basis_.center, np.multiply(a.basis_.center, 1000.0), rtol=1e-9)


# --- 4. frames of one vehicle -------------------------------------------------------------------


@pytest.mark.parametrize("likelihood", ["exact", "hsgp"])
def test_frames_of_one_vehicle(us101, likelihood):
    """Now and before: frames that hold one vehicle each fit with the default settings (the
    length-scale prior falls back from the nearest-neighbour spacing within frames, which needs
    two vehicles, to sqrt(bounding-box area / vehicles per frame)), and every result is finite."""
    frames = from_rows([r[:1] for r in rows_of(us101)])
    model = fit(frames, likelihood=likelihood)
    a, b = model.length_scale_prior_
    assert np.isfinite(a * b) and a * b > 0
    assert_usable(model, frames)


# --- 5. a single frame --------------------------------------------------------------------------


def test_a_single_frame_with_the_pilot_noise_is_a_typed_error(us101):
    """noise_var="pilot" holds out frames to choose the noise, so one frame is an
    InvalidInputError that says to pass a number; the default ("auto": sampled in the chain)
    fits one frame."""
    with pytest.raises(dpgp.InvalidInputError, match="noise_var='auto' needs at least"):
        fit(us101[:1], noise_var="pilot")
    assert fit(us101[:1]).n_patterns_ == 1


@pytest.mark.parametrize("likelihood", ["exact", "hsgp"])
def test_a_single_frame(us101, likelihood):
    """Now and before: one frame with noise_var given fits one pattern, and predict, score,
    velocity_field, simulate and sample_scenarios all work."""
    frame = us101[:1]
    model = fit(frame, likelihood=likelihood, noise_var=1.0)
    assert model.n_patterns_ == 1 and model.predict(frame).tolist() == [0]
    assert_usable(model, frame)
    scenarios = model.sample_scenarios(2, steps=3, seed=0).to_pandas()
    assert np.all(np.isfinite(scenarios[["x", "y", "vx", "vy"]].to_numpy()))


def test_a_single_vehicle_in_a_single_frame(us101):
    """One vehicle in all: the defaults cannot set a length scale or a signal variance from it
    (typed errors naming the setting to pass); with them passed it fits, and simulate now works
    too. Before: simulate and sample_scenarios raised InvalidInputError about a roi the user
    never passed (the default, the vehicle's bounding box, has zero width); now an axis of zero
    width is widened by the largest length scale."""
    frame = from_rows([rows_of(us101)[0][:1]])
    with pytest.raises(dpgp.InvalidInputError, match="length_scale_prior"):
        fit(frame, noise_var=1.0)
    with pytest.raises(dpgp.InvalidInputError, match="signal_var"):
        fit(frame, noise_var=1.0, length_scale_prior=(10.0, 1.0))
    model = fit(frame, noise_var=1.0, length_scale_prior=(10.0, 1.0), signal_var=1.0)
    assert_usable(model, frame)
    x0, x1, y0, y1 = model.simulate(0, steps=3).roi
    assert x1 - x0 == pytest.approx(2 * model.length_scales_[0, 0]) and y1 - y0 == pytest.approx(
        2 * model.length_scales_[0, 1]
    )
    assert len(model.sample_scenarios(2, steps=3, seed=0).to_pandas()) > 0
