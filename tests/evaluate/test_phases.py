"""Phases above the patterns (issue 20): the HMM over a fit's pattern labels, against brute force."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from dpgp.data.timeorder import TimeOrder
from dpgp.evaluate.phases import fit_phases, hmm_log_likelihood, viterbi
from dpgp.exceptions import InvalidInputError


def _order(n: int, dt: float = 0.5, gaps: tuple[int, ...] = ()) -> TimeOrder:
    """``n`` frames in time order, unbroken except before each frame index in ``gaps``."""
    nxt = np.r_[np.arange(1, n), -1]
    prev = np.r_[-1, np.arange(n - 1)]
    for g in gaps:
        nxt[g - 1], prev[g] = -1, -1
    return TimeOrder(np.zeros(n, dtype=np.int64), np.arange(n) * dt, dt, nxt, prev)


def _hmm(seed: int, p: int = 2, k: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.dirichlet(np.ones(k), size=p), rng.dirichlet(np.ones(p), size=p), rng.dirichlet(np.ones(p))


def _emit(z, t: int, emission, j: int) -> float:
    """log P(frame t | phase j): the label's probability, or for evidence rows (a (T, K) array of
    likelihoods) the phase's mixture of them."""
    z = np.asarray(z)
    return float(np.log(emission[j, z[t]] if z.ndim == 1 else emission[j] @ z[t]))


def _path_log_prob(z, path, emission, trans, start) -> float:
    lp = np.log(start[path[0]]) + _emit(z, 0, emission, path[0])
    for t in range(1, len(z)):
        lp += np.log(trans[path[t - 1], path[t]]) + _emit(z, t, emission, path[t])
    return float(lp)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_forward_pass_and_viterbi_match_every_path_enumerated(seed):
    emission, trans, start = _hmm(seed)
    z = np.random.default_rng(10 + seed).integers(0, 3, size=6)
    paths = list(itertools.product(range(2), repeat=len(z)))
    lps = np.array([_path_log_prob(z, p, emission, trans, start) for p in paths])
    total = np.log(np.exp(lps - lps.max()).sum()) + lps.max()
    assert hmm_log_likelihood([z], emission, trans, start) == pytest.approx(total, abs=1e-10)
    assert tuple(viterbi(z, emission, trans, start)) == paths[int(np.argmax(lps))]


def _two_phases(cycles: int = 10, length: int = 40, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Phase A emits patterns 0 and 1, phase B patterns 1 (shared) and 2, each frame by chance:
    labels flicker within a phase, the phases alternate every ``length`` frames."""
    rng = np.random.default_rng(seed)
    truth = np.tile(np.r_[np.zeros(length, int), np.ones(length, int)], cycles)
    labels = np.where(truth == 0, rng.choice([0, 1], size=len(truth)), rng.choice([1, 2], size=len(truth)))
    return labels, truth


def test_two_alternating_phases_with_a_shared_pattern_are_recovered():
    labels, truth = _two_phases()
    order = _order(len(labels))
    ph = fit_phases(labels, order, 2, seed=0)
    agree = max(np.mean(ph.labels == truth), np.mean(ph.labels != truth))
    assert agree > 0.97
    assert ph.transitions.share_same > 0.97
    # a phase lasts 40 frames of 0.5 s; the first and last runs are cut by the recording
    inner = ph.transitions.runs[ph.transitions.runs[:, 3] == 0]
    assert np.median(inner[:, 2]) * 0.5 == pytest.approx(20.0, abs=1.0)
    # the shared pattern belongs to both phases, the others to one each
    big = np.argmax(ph.emission[:, 0])
    assert ph.emission[big, 0] > 0.4 and ph.emission[1 - big, 0] < 0.02
    assert min(ph.emission[:, 1]) > 0.4
    # inside a phase, changes only between its own patterns
    assert ph.within[big, :, 2].sum() == 0 and ph.within[1 - big, :, 0].sum() == 0
    # BIC: two phases, not one and not more
    auto = fit_phases(labels, order, "auto", seed=0, max_phases=4)
    assert auto.n_phases == 2 and min(auto.bic, key=auto.bic.get) == 2


def test_em_does_not_lower_the_likelihood_and_gaps_split_the_sequence():
    labels, _ = _two_phases(cycles=4, seed=1)
    order = _order(len(labels), gaps=(100, 200))
    short = fit_phases(labels, order, 2, seed=3, restarts=1, max_iter=1)
    long = fit_phases(labels, order, 2, seed=3, restarts=1, max_iter=100)
    assert long.log_likelihood >= short.log_likelihood - 1e-9
    assert len(order.sequences()) == 3
    assert long.transitions.entry.sum() == 3  # three unbroken recordings


def test_bad_arguments_are_clear_errors():
    labels, _ = _two_phases(cycles=1)
    order = _order(len(labels))
    for bad in (0, -1, 2.5, True, "many"):
        with pytest.raises(InvalidInputError, match="n_phases"):
            fit_phases(labels, order, bad)
    with pytest.raises(InvalidInputError, match="labels"):
        fit_phases(labels[:-1], order, 2)
    with pytest.raises(InvalidInputError, match="restarts"):
        fit_phases(labels, order, 2, restarts=0)


def test_a_fit_has_phases_and_a_plot_of_them():
    import dpgp

    f = dpgp.datasets.synthetic("intersection", n_frames=60, seed=4)
    m = dpgp.DPGP(iterations=2, seed=0, progress=False).fit(f)
    ph = m.phases(2)
    assert ph.labels.shape == (60,) and ph.emission.shape == (2, m.n_patterns_)
    assert np.allclose(ph.emission.sum(axis=1), 1) and np.allclose(ph.trans.sum(axis=1), 1)
    assert "phases: 2" in ph.summary()
    fig = dpgp.plot.phases(m, 2)
    assert len(fig.axes) == 3


def _hsmm_path_log_prob(z, path, emission, trans, start, lp) -> float:
    """A state path's log-probability under the explicit-duration model, written out run by run:
    the first run's duration by the residual life (cut by the recording's start), the last run's
    by the survival (cut by its end), runs longer than the model holds impossible."""
    d_max = lp.shape[1]
    pmf = np.exp(lp)
    surv = np.cumsum(pmf[:, ::-1], axis=1)[:, ::-1]
    res = surv / (pmf * np.arange(1, d_max + 1)).sum(axis=1, keepdims=True)
    res_surv = np.cumsum(res[:, ::-1], axis=1)[:, ::-1]
    cut = np.flatnonzero(np.diff(path)) + 1
    runs = list(zip(np.r_[0, cut], np.r_[cut, len(path)]))
    if any(b - a > d_max for a, b in runs):
        return -np.inf
    lp_path = np.log(start[path[0]]) + sum(_emit(z, t, emission, path[t]) for t in range(len(z)))
    for i, (a, b) in enumerate(runs):
        r, n = path[a], b - a
        first, last = i == 0, i == len(runs) - 1
        table = (res_surv if last else res) if first else (surv if last else pmf)
        lp_path += np.log(table[r, n - 1])
        if not last:
            lp_path += np.log(trans[r, path[b]])
    return float(lp_path)


@pytest.mark.parametrize("kind", ["labels", "evidence"])
@pytest.mark.parametrize("d_max", [7, 3])
@pytest.mark.parametrize("seed", [0, 1])
def test_the_semi_markov_pass_and_viterbi_match_every_path_enumerated(seed, d_max, kind):
    from dpgp.evaluate.phases import _Evidence, _hsmm_pass, _hsmm_viterbi, duration_log_pmf

    rng = np.random.default_rng(seed)
    emission = rng.dirichlet(np.ones(3), size=2)
    trans = np.array([[0.0, 1.0], [1.0, 0.0]])
    start = rng.dirichlet(np.ones(2))
    lp = duration_log_pmf(np.log(np.array([2.0, 3.5])), np.array([0.6, 0.4]), d_max)
    z = rng.integers(0, 3, size=7) if kind == "labels" else _evidence(30 + seed, n=7)
    obs = z if kind == "labels" else _Evidence(z)
    paths = [np.array(p) for p in itertools.product(range(2), repeat=len(z))]
    lps = np.array([_hsmm_path_log_prob(z, p, emission, trans, start, lp) for p in paths])
    total = np.log(np.exp(lps - lps.max()).sum()) + lps.max()
    with np.errstate(divide="ignore"):
        ll, stats = _hsmm_pass(obs, np.log(emission), np.log(trans), np.log(start), lp)
    assert ll == pytest.approx(total, abs=1e-9)
    # each frame's phase posterior against the enumerated paths'
    post = np.exp(lps - total)
    want = np.array([[post[[p[t] == j for p in paths]].sum() for j in range(2)] for t in range(len(z))])
    np.testing.assert_allclose(stats["occ"], want, atol=1e-9)
    best = _hsmm_viterbi(obs, emission, trans, start, lp)  # a most probable path (ties happen)
    assert _hsmm_path_log_prob(z, best, emission, trans, start, lp) == pytest.approx(lps.max(), abs=1e-12)


def test_semi_markov_phases_recover_a_fixed_time_cycle():
    # two phases of 20 s each (40 frames) that share a pattern: durations learned near 20 s, every
    # inner run decoded at 20 s (a fixed-time signal), the likelihood above the HMM's
    labels, truth = _two_phases(cycles=8, seed=2)
    order = _order(len(labels))
    semi = fit_phases(labels, order, 2, seed=0, restarts=2, durations=True, max_duration=60.0)
    agree = max(np.mean(semi.labels == truth), np.mean(semi.labels != truth))
    assert agree > 0.97
    assert semi.durations is not None and np.allclose(np.exp(semi.durations[:, 0]), 20.0, rtol=0.1)
    inner = semi.transitions.runs[semi.transitions.runs[:, 3] == 0]
    assert np.all(np.abs(inner[:, 2] * 0.5 - 20.0) <= 1.5)
    hmm = fit_phases(labels, order, 2, seed=0, restarts=2)
    assert semi.log_likelihood > hmm.log_likelihood
    assert semi.sequence_log_likelihood([labels]) == pytest.approx(semi.log_likelihood, rel=1e-9)


# --- phases fitted to each frame's likelihood under every pattern (evidence) ------------------------
def _evidence(seed: int, n: int = 6, k: int = 3) -> np.ndarray:
    """(n, k) likelihoods, rows scaled to a maximum of 1, one entry 0 (a pattern that cannot have
    the frame)."""
    like = np.random.default_rng(seed).uniform(0.05, 1.0, size=(n, k))
    like[1, 2] = 0.0
    return like / like.max(axis=1, keepdims=True)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_evidence_forward_pass_posteriors_and_viterbi_match_every_path_enumerated(seed):
    from dpgp.evaluate.phases import _Evidence, _forward_backward

    emission, trans, start = _hmm(seed)
    like = _evidence(20 + seed)
    paths = list(itertools.product(range(2), repeat=len(like)))
    lps = np.array([_path_log_prob(like, p, emission, trans, start) for p in paths])
    total = np.log(np.exp(lps - lps.max()).sum()) + lps.max()
    obs = _Evidence(like)
    assert hmm_log_likelihood([obs], emission, trans, start) == pytest.approx(total, abs=1e-10)
    assert tuple(viterbi(obs, emission, trans, start)) == paths[int(np.argmax(lps))]
    _, gamma, _ = _forward_backward(obs, emission, trans, start)
    post = np.exp(lps - total)
    want = np.array([[post[[p[t] == j for p in paths]].sum() for j in range(2)] for t in range(len(like))])
    np.testing.assert_allclose(gamma, want, atol=1e-10)
    # labels are the evidence of one-hot rows
    z = np.random.default_rng(seed).integers(0, 3, size=6)
    assert hmm_log_likelihood([_Evidence(np.eye(3)[z])], emission, trans, start) == pytest.approx(
        hmm_log_likelihood([z], emission, trans, start), abs=1e-12
    )


def _ambiguous_labels(cycles: int = 5, length: int = 40, seed: int = 0):
    """Frames that patterns 0 and 1 explain best, either one by chance, in both phases: the
    labels (each frame's most likely pattern) say nothing of the phase. What does is the pattern
    that explains every frame nearly as well: 2 in phase A, 3 in phase B."""
    rng = np.random.default_rng(seed)
    truth = np.tile(np.r_[np.zeros(length, int), np.ones(length, int)], cycles)
    n = len(truth)
    first = rng.integers(0, 2, n)
    like = np.full((n, 4), 0.02)
    like[np.arange(n), first] = 1.0
    like[np.arange(n), 1 - first] = 0.3
    like[np.arange(n), 2 + truth] = rng.uniform(0.8, 0.95, n)
    ev = np.log(like) + rng.normal(0.0, 5.0, size=(n, 1))  # a per-frame constant: no posterior changes
    return np.argmax(ev, axis=1), ev, truth


def test_phases_from_evidence_see_what_labels_hide():
    labels, ev, truth = _ambiguous_labels()
    order = _order(len(labels))
    by_labels = fit_phases(labels, order, 2, seed=0, n_patterns=4)
    assert max(np.mean(by_labels.labels == truth), np.mean(by_labels.labels != truth)) < 0.6
    ph = fit_phases(labels, order, 2, seed=0, evidence=ev)
    assert max(np.mean(ph.labels == truth), np.mean(ph.labels != truth)) > 0.97
    # each phase: its own pattern that explains all its frames
    a = int(np.argmax(ph.emission[:, 2]))
    assert ph.emission[a, 2] > 0.8 and ph.emission[1 - a, 3] > 0.8
    # the reported likelihood is the frames' (the per-frame constants counted), EM only raises it
    short = fit_phases(labels, order, 2, seed=0, restarts=1, max_iter=1, evidence=ev)
    assert ph.log_likelihood >= short.log_likelihood - 1e-9
    assert ph.log_likelihood < ev.max(axis=1).sum()
    semi = fit_phases(labels, order, 2, seed=0, restarts=1, evidence=ev, durations=True, max_duration=60.0)
    assert max(np.mean(semi.labels == truth), np.mean(semi.labels != truth)) > 0.97


def test_one_hot_evidence_gives_the_labels_fit():
    labels, _ = _two_phases(cycles=3, seed=4)
    order = _order(len(labels))
    a = fit_phases(labels, order, 2, seed=1, restarts=2)
    with np.errstate(divide="ignore"):
        b = fit_phases(labels, order, 2, seed=1, restarts=2, evidence=np.log(np.eye(3)[labels]))
    np.testing.assert_array_equal(a.labels, b.labels)
    np.testing.assert_allclose(b.emission, a.emission, atol=1e-9)
    assert b.log_likelihood == pytest.approx(a.log_likelihood, abs=1e-8)


def test_bad_evidence_is_a_clear_error():
    labels, _ = _two_phases(cycles=1)
    order = _order(len(labels))
    ev = np.zeros((len(labels), 3))
    for bad in (ev[:-1], ev[:, :2], np.where(np.arange(3) == 1, np.nan, ev), np.full_like(ev, np.inf), ev[:, 0]):
        with pytest.raises(InvalidInputError, match="evidence"):
            fit_phases(labels, order, 2, evidence=bad)
    with pytest.raises(InvalidInputError, match="finite log-likelihood"):
        fit_phases(labels, order, 2, evidence=np.where(np.arange(len(labels))[:, None] == 3, -np.inf, ev))


def test_a_fit_has_phases_from_its_frames_likelihoods():
    import dpgp

    f = dpgp.datasets.synthetic("intersection", n_frames=60, seed=4)
    m = dpgp.DPGP(iterations=2, seed=0, progress=False).fit(f)
    ph = m.phases(2, evidence="likelihood")
    assert ph.labels.shape == (60,) and ph.emission.shape == (2, m.n_patterns_)
    want = fit_phases(m.labels_, m.frames_, 2, n_patterns=m.n_patterns_, evidence=m.training_log_likelihoods())
    np.testing.assert_array_equal(ph.labels, want.labels)
    assert ph.log_likelihood == pytest.approx(want.log_likelihood)
    assert m.phases(2, evidence="likelihood") is ph  # cached, apart from the labels' fit
    assert m.phases(2) is not ph
    with pytest.raises(InvalidInputError, match="evidence"):
        m.phases(2, evidence="votes")
    fig = dpgp.plot.phases(m, m.phases(3, evidence="likelihood", cycle=True))
    assert len(fig.axes) == 3


def _stages_with_returns(cycles: int = 6, length: int = 30, seed: int = 0):
    """Three stages in a fixed cycle 0 → 1 → 2, ``length`` frames each; stage s emits patterns s
    and s + 3 by chance. Mid-way through every stage 1, eight frames look like stage 0 (a brief
    return, as vehicles of the phase before clear a junction)."""
    rng = np.random.default_rng(seed)
    truth = np.tile(np.repeat(np.arange(3), length), cycles)
    labels = truth + 3 * rng.integers(0, 2, len(truth))
    starts = np.flatnonzero(np.diff(np.r_[-1, truth]) != 0)
    for a in starts[truth[starts] == 1]:
        labels[a + length // 2 - 4 : a + length // 2 + 4] = 0
    return labels, truth


def test_a_cycle_of_phases_keeps_brief_returns_inside_their_stage():
    labels, truth = _stages_with_returns()
    order = _order(len(labels))
    free = fit_phases(labels, order, 3, seed=0)
    cyc = fit_phases(labels, order, 3, seed=0, cycle=True)
    # only the next stage may follow: zeros elsewhere off the diagonal, the order 0 → 1 → 2 → 0
    off = cyc.trans.copy()
    np.fill_diagonal(off, 0.0)
    assert np.all((off > 0).sum(axis=1) == 1)
    assert all(off[j, (j + 1) % 3] > 0 for j in range(3))
    # the free model decodes each return as a run of the stage before; the cycle cannot go back
    assert len(free.transitions.runs) > len(cyc.transitions.runs)
    inner = cyc.transitions.runs[cyc.transitions.runs[:, 3] == 0]
    assert np.all(inner[:, 2] == 30)
    # BIC counts one change per phase (to the next), not two
    from dpgp.evaluate.phases import _n_params

    assert _n_params(3, 6, cycle=True) == _n_params(3, 6) - 3
    assert _n_params(3, 6, durations=True, cycle=True) == _n_params(3, 6, durations=True) - 3
    # a cycle under the semi-Markov model too
    semi = fit_phases(labels, order, 3, seed=0, cycle=True, durations=True, max_duration=40.0, restarts=1)
    inner = semi.transitions.runs[semi.transitions.runs[:, 3] == 0]
    assert np.all(np.abs(inner[:, 2] - 30) <= 1)
    # the recorded cycles, from the stage numbered 0 (the largest, here the second of the truth):
    # 5 complete, the 6th cut by the recording's end
    assert cyc.cycle and not free.cycle and free.cycles is None
    np.testing.assert_array_equal(cyc.cycles, np.full((5, 3), 30))
    assert np.all(np.abs(semi.cycles - 30) <= 1) and len(semi.cycles) >= 4
    assert "cycle: 5 complete recorded cycles, median 45.0 s" in cyc.summary()


def test_recorded_cycles_are_the_complete_runs_of_every_stage_in_order():
    from dpgp.evaluate.phases import recorded_cycles
    from dpgp.evaluate.transitions import count_transitions

    def cycles(path, order):
        return recorded_cycles(count_transitions(path, order).runs, 3)

    #            cut by the start | cycle (2, 3, 1)     | cycle (1, 1, 2)  | cut by the end
    path = np.array([1, 2, 2] + [0, 0, 1, 1, 1, 2] + [0, 1, 2, 2] + [0, 1])
    np.testing.assert_array_equal(cycles(path, _order(len(path))), [[2, 3, 1], [1, 1, 2]])
    # two recordings: a cycle does not run across the gap between them
    np.testing.assert_array_equal(cycles(path, _order(len(path), gaps=(6,))), [[1, 1, 2]])
    # a stage skipped is not a cycle
    skipped = np.array([1, 0, 2, 0, 1, 2, 0])
    np.testing.assert_array_equal(cycles(skipped, _order(7)), [[1, 1, 1]])
