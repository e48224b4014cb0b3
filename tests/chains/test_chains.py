"""dpgp.fit_chains on local worker processes: deterministic chains, the stopping rule, the
summaries (R̂/ESS as dpgp.diagnostics computes them, similarity, point estimate, best model),
a worker process that dies. Ctrl-C is tested in test_ctrl_c.py, the Dask engine in
test_chains_dask.py."""

import threading
import time
import warnings

import numpy as np
import pytest

import dpgp
from dpgp import InvalidInputError, diagnostics, partition

# The synthetic frames' true noise variance (0.7²): the posterior then concentrates on the four
# true patterns, which the point estimate must recover. (test_chains_dask.py runs the defaults.)
SETTINGS = dict(iterations=12, block=4, seed=5, progress=False, noise_var=0.49)


@pytest.fixture(scope="module")
def frames():
    return dpgp.datasets.synthetic("intersection", n_frames=60, seed=0)


@pytest.fixture(scope="module")
def chains(frames):
    return dpgp.fit_chains(frames, 4, **SETTINGS)


def test_four_chains_run_and_hold_their_traces(chains, frames):
    assert chains.names == ["chain0", "chain1", "chain2", "chain3"]
    assert chains.n_chains == 4 and chains.n_sweeps == 12 and chains.burn_in == 6
    for q in ("log_joint", "n_patterns", "alpha", "moves", "seconds"):
        assert chains.traces[q].shape == (4, 12)
    assert chains.labels.shape == (4, 12, len(frames))
    assert not chains.converged_ and "12 sweeps" in chains.stop_reason_ and chains.failures_ == {}
    # chains differ (independent seeds); each model is a fitted DPGP at its chain's last state
    assert len(set(chains.traces["log_joint"][:, -1])) == 4
    for model, labels, k in zip(chains.models, chains.labels[:, -1], chains.traces["n_patterns"][:, -1]):
        assert model.n_patterns_ == k
        assert dpgp.adjusted_rand_index(model.labels_, labels) == 1.0
        assert model.predict(frames[:3]).shape == (3,)


def test_same_seed_same_chains_whatever_the_number_of_workers(chains, frames):
    again = dpgp.fit_chains(frames, 4, n_workers=1, **SETTINGS)
    np.testing.assert_array_equal(again.labels, chains.labels)
    for q in ("log_joint", "n_patterns", "alpha", "moves"):
        np.testing.assert_array_equal(again.traces[q], chains.traces[q])
    other = dpgp.fit_chains(frames, 2, **{**SETTINGS, "seed": 6})
    assert not np.array_equal(other.traces["log_joint"], chains.traces["log_joint"][:2])


def test_diagnostics_are_those_of_the_kept_draws(chains):
    rhat, bulk, tail = chains.rhat(), chains.ess("bulk"), chains.ess("tail")
    assert set(rhat) == {"log_joint", "n_patterns", "alpha"}
    for q in rhat:
        kept = chains.traces[q][:, 6:]
        np.testing.assert_equal(rhat[q], diagnostics.rhat(kept))
        assert bulk[q] == diagnostics.ess_bulk(kept) and tail[q] == diagnostics.ess_tail(kept)
    table = chains.summary()
    assert list(table.columns) == ["mean", "sd", "rhat", "ess_bulk", "ess_tail", "min"]
    chains.burn_in = 2
    assert chains.draws("alpha").shape == (4, 10)
    chains.burn_in = 6
    with pytest.raises(InvalidInputError, match="burn_in"):
        chains.burn_in = 12


def test_summary_reports_how_far_the_chains_summary_partitions_agree(chains):
    """Each chain's summary partition is the point estimate of its own kept sweeps; the summary's
    ``partition_ari`` row is the adjusted Rand index of every pair of them (recomputed here)."""
    est = chains.chain_estimates()
    for c in range(chains.n_chains):
        own = partition.salso(chains.labels[c, chains.burn_in :], "vi", n_runs=4, init=chains.labels[c, -1:], seed=5)
        np.testing.assert_array_equal(est[c], own.labels)
    agree = chains.agreement()
    pairs = [dpgp.adjusted_rand_index(est[a], est[b]) for a in range(4) for b in range(a + 1, 4)]
    np.testing.assert_allclose(agree[np.triu_indices(4, 1)], pairs)
    np.testing.assert_array_equal(np.diag(agree), 1.0)
    row = chains.summary().loc["partition_ari"]
    assert row["mean"] == pytest.approx(np.mean(pairs)) and row["min"] == pytest.approx(min(pairs))


def test_dispersed_chains_start_from_one_pattern_and_from_many(frames):
    ch = dpgp.fit_chains(frames, 2, iterations=1, block=1, seed=5, progress=False, init="dispersed")
    k = ch.traces["n_patterns"][:, 0]
    assert k[0] < k[1], k  # after one sweep, the chain from one pattern has fewer than the one from 60
    starts = [dpgp.DPGP(iterations=0, init=i, progress=False).fit(frames).n_patterns_ for i in ("one", "many")]
    assert starts == [1, 60]
    with pytest.raises(InvalidInputError, match="init"):
        dpgp.fit_chains(frames, 2, iterations=1, progress=False, init="scattered")


def test_to_inference_data_round_trips_through_arviz(chains):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        az = pytest.importorskip("arviz")
        idata = chains.to_inference_data()
        np.testing.assert_allclose(
            float(az.rhat(idata, method="rank")["log_joint"]), chains.rhat()["log_joint"], rtol=1e-6
        )
    assert idata.posterior["alpha"].shape == (4, 6)
    assert idata.warmup_posterior["alpha"].shape == (4, 6)


def test_point_estimate_similarity_and_best_model(chains, frames, tmp_path):
    est = chains.point_estimate("vi")
    kept = chains.kept_labels()
    assert kept.shape == (24, len(frames))
    assert est.expected_loss == pytest.approx(partition.expected_loss(est.labels, kept, "vi"))
    assert dpgp.adjusted_rand_index(est.labels, frames.labels) >= 0.95  # the synthetic truth: 4 patterns
    assert chains.point_estimate("binder").loss == "binder"
    sim = chains.similarity()
    assert sim.shape == (60, 60)
    np.testing.assert_allclose(chains.similarity(rows=[0, 7]), sim[[0, 7]])
    ball = chains.credible_ball("vi", level=0.9)
    assert ball.radius >= 0
    model = chains.best_model("vi")
    np.testing.assert_array_equal(model.labels_, est.labels)
    assert model.n_patterns_ == est.n_clusters
    assert model.chain_summary_["point_estimate"]["expected_loss"] == pytest.approx(est.expected_loss)
    sim_run = model.simulate(0, steps=3)
    assert sim_run.positions.shape[0] == 4
    path = tmp_path / "best.npz"
    model.save(path)
    loaded = dpgp.DPGP.load(path)
    np.testing.assert_array_equal(loaded.labels_, model.labels_)
    assert loaded.chain_summary_["rhat"].keys() == model.chain_summary_["rhat"].keys()
    assert loaded.chain_summary_["burn_in"] == 6
    assert getattr(loaded, "label_trace_", None) is None  # traces only when asked
    with_traces = chains.best_model("vi", keep_traces=True)
    assert with_traces.label_trace_.shape == (24, len(frames))


def test_until_converged_stops_by_the_rule_and_says_why(frames):
    # Generous thresholds on data the chains agree on quickly (the synthetic highway's three
    # patterns, α fixed): the rule holds after a few blocks.
    highway = dpgp.datasets.synthetic("highway", n_frames=60, seed=0)
    ch = dpgp.fit_chains(highway, 3, until="converged", rhat=1.5, min_ess=5, block=4, max_iterations=40,
                         seed=1, progress=False, alpha=1.0)  # fmt: skip
    assert ch.converged_ and ch.stop_reason_.startswith("converged after")
    assert ch.n_sweeps % 4 == 0 and ch.n_sweeps <= 40
    last = ch.checks_[-1]
    assert last["ok"] and last["sweeps"] == ch.n_sweeps
    strict = dpgp.fit_chains(frames, 2, until="converged", rhat=1.0001, min_ess=10_000, block=3, max_iterations=6,
                             seed=1, progress=False)  # fmt: skip
    assert not strict.converged_ and "max_iterations=6" in strict.stop_reason_ and strict.n_sweeps == 6
    assert "ESS" in strict.stop_reason_


def test_convergence_rule_on_fixed_traces():
    rng = np.random.default_rng(0)
    good = {"a": rng.normal(size=(4, 400)), "k": np.full((4, 400), 3.0)}
    verdict = dpgp.chains.convergence(good, 0, 1.01, 100)
    assert verdict["ok"], verdict["why"]  # a quantity that never varies passes
    bad = {"a": rng.normal(size=(4, 400)) + np.arange(4)[:, None]}
    verdict = dpgp.chains.convergence(bad, 0, 1.01, 100)
    assert not verdict["ok"] and "R̂(a)" in verdict["why"]


def test_bad_arguments_raise_typed_errors(frames):
    with pytest.raises(InvalidInputError, match="n_chains"):
        dpgp.fit_chains(frames, 0)
    with pytest.raises(InvalidInputError, match="until"):
        dpgp.fit_chains(frames, until="forever")
    with pytest.raises(InvalidInputError, match="fit_chains' own"):
        dpgp.fit_chains(frames, iterations=3, store_labels=True)
    with pytest.raises(InvalidInputError, match="unknown DPGP setting"):
        dpgp.fit_chains(frames, iterations=3, sweeps=3)
    with pytest.raises(InvalidInputError, match="assignment"):
        dpgp.fit_chains(frames, iterations=3, assignment="greedy")
    with pytest.raises(InvalidInputError, match="burn_in"):
        dpgp.fit_chains(frames, iterations=3, burn_in=-1)


def test_a_local_worker_that_dies_is_replaced_and_its_block_rerun(frames, chains):
    """Kill one worker process mid-run: the pool is restarted, the lost blocks run again
    (they are deterministic), and the chains come out as in an undisturbed run."""
    import psutil

    me = psutil.Process()
    before = {p.pid for p in me.children(recursive=True)}
    killed: list[int] = []

    def kill_one() -> None:
        deadline = time.time() + 60
        while time.time() < deadline and not killed:
            workers = [p for p in me.children() if p.pid not in before and "spawn_main" in " ".join(p.cmdline())]
            if len(workers) >= 2:
                time.sleep(0.3)  # blocks are submitted; the worker is still starting or running one
                workers[0].kill()
                killed.append(workers[0].pid)
            time.sleep(0.05)

    thread = threading.Thread(target=kill_one)
    thread.start()
    again = dpgp.fit_chains(frames, 4, **SETTINGS)
    thread.join()
    assert killed and again.retried_, "the kill did not land while blocks were running"
    assert again.failures_ == {}
    np.testing.assert_array_equal(again.labels, chains.labels)


def test_chain_figures(chains):
    fig = dpgp.plot.chain_trace(chains)
    assert len(fig.axes) == 3 and all(len(ax.lines) == 4 for ax in fig.axes)
    assert "12 sweeps" in fig._suptitle.get_text()
    ax = dpgp.plot.similarity(chains)
    assert ax.images[0].get_array().shape == (60, 60)
    assert dpgp.plot.similarity(chains, max_items=20).images[0].get_array().shape == (20, 20)
    ax = dpgp.plot.rhat(chains)
    labels = [line.get_label() for line in ax.lines]
    assert labels[0] == "log joint" and labels[1].startswith("K") and labels[3] == "threshold 1.01"


def test_cli_fits_chains_saves_the_point_estimate_and_info_shows_the_diagnostics(frames, tmp_path, capsys):
    from dpgp import cli

    data = tmp_path / "frames.csv"
    frames.to_pandas().to_csv(data, index=False)
    out = tmp_path / "chains.npz"
    assert cli.main(["fit", str(data), "-o", str(out), "--chains", "2", "--iterations", "8", "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "Chains(2 chains × 8 sweeps" in text and "ess_bulk" in text and "point estimate (vi)" in text
    model = dpgp.DPGP.load(out)
    assert model.chain_summary_["n_chains"] == 2 and model.chain_summary_["n_sweeps"] == 8
    assert cli.main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "chains: 2 × 8 sweeps, burn-in 4" in text and "R̂: log joint" in text and "ESS bulk" in text
    assert cli.main(["fit", str(data), "-o", str(out), "--until-converged", "--no-progress"]) == 1
    assert "go with --chains" in capsys.readouterr().err


def test_every_block_and_the_best_model_keep_the_likelihood_of_the_first(frames):
    """Blocks after the first rebuild the model from its state: they must sample the model the
    first block chose (here hsgp, with its basis), and so must the point-estimate model, also
    when no setting was left to "auto"."""
    ch = dpgp.fit_chains(frames, 2, iterations=8, block=4, seed=2, progress=False, likelihood="hsgp",
                         noise_var=0.49, length_scale_prior=(10.0, 1.0))  # fmt: skip
    basis = ch.models[0].basis_
    assert basis is not None
    assert all(m.likelihood_ == "hsgp" and m.basis_ == basis for m in ch.models)
    best = ch.best_model()
    assert best.likelihood_ == "hsgp" and best.basis_ == basis
