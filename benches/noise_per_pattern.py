"""Global or per-pattern observation noise (issue 16, item 2): held-out score and mixing evidence.

The sampler draws ONE noise pair (σ²_n,x, σ²_n,y) shared by every pattern. This bench asks what a
per-pattern pair would give, at the same partition, without a per-pattern sampler:

1. each shared data set with a time order is split 70/30 in time (:func:`split_in_time`; US-101:
   its first 400 frames) and fitted with every default (global noise sampled), ``iterations``
   sweeps, ``n_threads=1``, seeds 0..S-1;
2. holding that fit's final partition, length scales, signal variances, means and α, each
   pattern gets its own noise posterior: the SAME prior as the sampler's
   (``log(σ²/s_d²) ~ N(log 0.1, 2²)``) times that pattern's own marginal likelihood, for each
   output ``d`` (the two outputs are independent GPs, so the posterior is a product of two 1-D
   posteriors). It is evaluated on a grid around its mode (coarse grid over the prior, Brent,
   then 25 points over ± 6 Laplace sds), through a core sampler holding that pattern alone
   (``model._new_sampler``, so the engine, exact or hsgp, and its basis are the fit's);
3. the held-out density per test vehicle, ``log Σ_k π_k p(V | X, D_k) + π_new p_new(V | X)`` with the
   DP's predictive weights, is computed (a) with the global noise: this reproduces the
   package's ``score_samples(test, positions=False)`` (checked to 1e-6 per frame), and (b) with
   each pattern's own noise, ``p(V | X, D_k)`` averaged over that pattern's noise posterior and
   the new-pattern term averaged over the noise prior (9 × 9 Gauss–Hermite nodes); (c) with
   one posterior draw of each pattern's noise (what a per-pattern chain's last state would
   hold). ``blind`` is the position-blind Gaussian of ``model.evaluate(test).table``; ``avg`` is
   the package's posterior-averaged score (``evaluate``'s default) with the global noise.

Mixing evidence, per fit: the spread of the patterns' posterior-mean noises (largest / smallest,
each output, patterns with ≥ 3 frames), the posterior sd of ``log σ²`` of the median pattern and
of patterns with ≤ 5 frames, and ``KL``, the mean over patterns of KL(noise posterior ‖ prior)
summed over both outputs: the expected log Metropolis–Hastings penalty a split or merge pays if
it proposes the new pattern's noise from the prior (a proposal fitted to the pattern instead
costs a 1-D optimisation per output per move: ``evals`` is what this bench spent per pattern).
``gain`` is the mean over patterns of max_σ log [prior × marginal] − log [prior × marginal] at the
global noise: how much each pattern would gain by its own noise.

    PYTHONPATH=python python benches/noise_per_pattern.py [--quick] [--seeds 3] [--iterations 60] [--only eth,zara01]

``--quick``: the SUMO left turn and Lankershim only, seed 0, 20 sweeps. Densities are nats per
test vehicle (higher is better).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.optimize import minimize_scalar
from scipy.special import logsumexp

import dpgp
from dpgp.evaluate import split_in_time
from dpgp.gp.defaults import NOISE_PRIOR

sys.path.insert(0, str(Path(__file__).resolve().parent))
from evaluate import datasets  # noqa: E402  (the held-out bench's loaders)

DATA_SETS = ("us101", "eth", "zara01", "peachtree", "sumo_left_turn", "lankershim")
US101_FRAMES = 400
COARSE = 15  # coarse grid over the prior's ± 9 (log scale)
FINE = 25  # final grid over the mode ± 6 Laplace sds
HERMITE = 9  # Gauss–Hermite nodes per output for the new pattern's noise


def load(name: str):
    frames, _ = datasets()[name][0]()
    if name == "us101":
        frames = frames[:US101_FRAMES]
    return split_in_time(frames)


def pattern_sampler(model: dpgp.DPGP, rows: np.ndarray, ls: np.ndarray):
    """A core sampler with the fit's settings over training frames ``rows``, all in one pattern
    with length scales ``ls``: its log joint, as the noise varies, is the noise prior plus that
    pattern's log marginal likelihood plus a constant."""
    s = model._new_sampler(model.frames_[rows])
    s.set_state(np.zeros(len(rows), dtype=np.int64), np.asarray(ls, dtype=np.float64).reshape(1, 2), model.alpha_)
    return s


def with_noise(base: tuple[float, float], d: int, x: float) -> tuple[float, float]:
    out = list(base)
    out[d] = float(np.exp(x))
    return (out[0], out[1])


def noise_posterior(s, base: tuple[float, float], d: int, centre: float, test) -> dict:
    """Pattern ``s``'s posterior of ``x = log σ²_n,d`` (the other output at the global noise) on
    a grid, with the test frames' scores at each grid point."""
    cache: dict[float, float] = {}

    def f(x: float) -> float:
        if x not in cache:
            s.set_noise_var(with_noise(base, d, x))
            cache[x] = float(s.log_joint())
        return cache[x]

    coarse = np.linspace(centre - 9, centre + 9, COARSE)
    fc = np.array([f(x) for x in coarse])
    i = int(np.argmax(fc))
    lo, hi = coarse[max(i - 1, 0)], coarse[min(i + 1, COARSE - 1)]
    res = minimize_scalar(lambda x: -f(x), bounds=(lo, hi), method="bounded", options={"xatol": 1e-4})
    mode = float(res.x) if -res.fun >= fc[i] else float(coarse[i])
    h = 0.01
    curv = (f(mode + h) - 2 * f(mode) + f(mode - h)) / h**2
    sd = float(np.clip(1 / np.sqrt(-curv), 1e-3, 3.0)) if curv < 0 else 3.0
    half = 6 * sd
    for _ in range(4):  # widen until both ends are far below the mode
        grid = np.linspace(mode - half, mode + half, FINE)
        lp = np.array([f(x) for x in grid])
        if lp[0] < lp.max() - 12 and lp[-1] < lp.max() - 12:
            break
        half *= 2
    dx = grid[1] - grid[0]
    logw = lp + np.log(dx) - logsumexp(lp + np.log(dx))  # posterior mass of each grid cell
    w = np.exp(logw)
    mean = float(w @ grid)
    prior = -0.5 * ((grid - centre) / NOISE_PRIOR[1]) ** 2 - np.log(NOISE_PRIOR[1] * np.sqrt(2 * np.pi))
    kl = float(w @ (logw - np.log(dx) - prior))
    scores = []
    for x in grid:
        s.set_noise_var(with_noise(base, d, x))
        scores.append(np.asarray(s.score_frames(test.xy, test.v, test.offsets)[0], dtype=np.float64)[:, 0])
    s.set_noise_var(base)
    return {
        "grid": grid, "logw": logw, "mean": mean, "sd": float(np.sqrt(w @ (grid - mean) ** 2)), "kl": kl,
        "gain": float(lp.max() - f(np.log(base[d]))), "scores": np.array(scores), "evals": len(cache),
    }  # fmt: skip


def new_term_prior_averaged(model: dpgp.DPGP, test, centres: np.ndarray) -> np.ndarray:
    """The new-pattern term of each test frame with its noise averaged over the prior
    (Gauss–Hermite in ``log σ²`` of each output), through a sampler over one training frame
    (the term depends on the settings, α and the seed, not on the training frames)."""
    s = pattern_sampler(model, np.array([0]), model.length_scales_[model.labels_[0]])
    t, wt = np.polynomial.hermite.hermgauss(HERMITE)
    xs = [centres[d] + np.sqrt(2) * NOISE_PRIOR[1] * t for d in range(2)]
    logw = np.log(wt / np.sqrt(np.pi))
    terms = []
    for i in range(HERMITE):
        for j in range(HERMITE):
            s.set_noise_var((float(np.exp(xs[0][i])), float(np.exp(xs[1][j]))))
            new = np.asarray(s.score_frames(test.xy, test.v, test.offsets)[1], dtype=np.float64)
            terms.append(logw[i] + logw[j] + new)
    return logsumexp(np.array(terms), axis=0)


def mixture(cols: np.ndarray, new: np.ndarray, counts: np.ndarray, alpha: float) -> np.ndarray:
    """Per test frame: log Σ_k π_k p_k + π_new p_new with the DP predictive weights."""
    n = counts.sum()
    log_prior = np.log(np.r_[counts, alpha]) - np.log(n + alpha)
    return logsumexp(np.column_stack([cols, new]) + log_prior, axis=1)


def one(name: str, train, test, seed: int, iterations: int) -> dict:
    t0 = time.perf_counter()
    model = dpgp.DPGP(iterations=iterations, seed=seed, n_threads=1, progress=False).fit(train)
    t_fit = time.perf_counter() - t0
    ev = model.evaluate(test).table
    vehicles = test.sizes.sum()
    package = model.score_samples(test, positions=False)
    base = tuple(float(x) for x in model.noise_var_)
    centres = np.log(np.asarray(model.params_.signal_var)) + NOISE_PRIOR[0]
    counts = np.bincount(model.labels_).astype(np.float64)
    rng = np.random.default_rng(1000 + seed)
    cols_global, cols_avg, cols_draw, post = [], [], [], []
    new_global = None
    for k in range(model.n_patterns_):
        s = pattern_sampler(model, np.flatnonzero(model.labels_ == k), model.length_scales_[k])
        scores, new = s.score_frames(test.xy, test.v, test.offsets)
        s0 = np.asarray(scores, dtype=np.float64)[:, 0]
        new_global = np.asarray(new, dtype=np.float64) if new_global is None else new_global
        cols_global.append(s0)
        pp = [noise_posterior(s, base, d, centres[d], test) for d in range(2)]
        post.append(pp)
        # Outputs are independent: E[p_x p_y] = E[p_x] E[p_y]; each grid's scores hold the
        # other output at the global noise, hence the - s0.
        avg = [logsumexp(p["logw"][:, None] + p["scores"], axis=0) for p in pp]
        cols_avg.append(avg[0] + avg[1] - s0)
        g = [rng.choice(FINE, p=np.exp(p["logw"]) / np.exp(p["logw"]).sum()) for p in pp]
        cols_draw.append(pp[0]["scores"][g[0]] + pp[1]["scores"][g[1]] - s0)
    glob = mixture(np.column_stack(cols_global), new_global, counts, model.alpha_)
    err = float(np.max(np.abs(glob - package)))
    if err > 1e-6:
        raise AssertionError(f"{name} seed {seed}: the global mixture is {err:.2g} from score_samples")
    new_prior = new_term_prior_averaged(model, test, centres)
    per = mixture(np.column_stack(cols_avg), new_prior, counts, model.alpha_)
    per_new_global = mixture(np.column_stack(cols_avg), new_global, counts, model.alpha_)
    draw = mixture(np.column_stack(cols_draw), new_prior, counts, model.alpha_)
    big = counts >= 3
    means = np.array([[p[d]["mean"] for d in range(2)] for p in post])  # (K, 2) log σ²
    sds = np.array([[p[d]["sd"] for d in range(2)] for p in post])
    small = counts <= 5
    ratio = np.exp(means[big].max(axis=0) - means[big].min(axis=0)) if big.sum() > 1 else np.array([1.0, 1.0])
    row = {
        "data": name,
        "seed": seed,
        "engine": model.likelihood_,
        "K": model.n_patterns_,
        "K >= 1%": int((counts / counts.sum() >= 0.01).sum()),
        "global": glob.sum() / vehicles,
        "per-pattern": per.sum() / vehicles,
        "per - global": (per.sum() - glob.sum()) / vehicles,
        "per (new at global)": per_new_global.sum() / vehicles,
        "per (one draw)": draw.sum() / vehicles,
        "avg (package)": ev.loc["dpgp", "log_density"],
        "blind": ev.loc["position_blind", "log_density"],
        "check |err|": err,
        "noise x/s2": base[0] / model.params_.signal_var[0],
        "noise y/s2": base[1] / model.params_.signal_var[1],
        "max/min x": ratio[0],
        "max/min y": ratio[1],
        "sd median": float(np.median(sds)),
        "sd <=5 frames": float(sds[small].mean()) if small.any() else float("nan"),
        "KL nats": float(np.mean([p[0]["kl"] + p[1]["kl"] for p in post])),
        "gain nats": float(np.mean([p[0]["gain"] + p[1]["gain"] for p in post])),
        "largest: own/global x": float(np.exp(means[0, 0]) / base[0]),
        "largest: own/global y": float(np.exp(means[0, 1]) / base[1]),
        "evals": int(np.mean([p[0]["evals"] + p[1]["evals"] for p in post])),
        "fit s": t_fit,
        "s": time.perf_counter() - t0,
    }
    print(f"{name} seed {seed}: global {row['global']:.3f} per-pattern {row['per-pattern']:.3f} "
          f"blind {row['blind']:.3f} K {row['K']} ({row['s']:.0f} s)", flush=True)  # fmt: skip
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=3, help="fit with seeds 0..SEEDS-1")
    ap.add_argument("--iterations", type=int, default=60, help="Gibbs sweeps per fit")
    ap.add_argument("--only", help="comma-separated subset of " + ",".join(DATA_SETS))
    ap.add_argument("--quick", action="store_true", help="SUMO left turn and Lankershim, seed 0, 20 sweeps")
    ap.add_argument("--csv", help="also write the rows here")
    args = ap.parse_args()
    names = args.only.split(",") if args.only else list(DATA_SETS)
    if args.quick:
        names, args.seeds, args.iterations = ["sumo_left_turn", "lankershim"], 1, 20
    rows = []
    for name in names:
        train, test = load(name)
        for seed in range(args.seeds):
            rows.append(one(name, train, test, seed, args.iterations))
    table = pd.DataFrame(rows).set_index(["data", "seed"])
    if args.csv:
        table.to_csv(args.csv)
    with pd.option_context("display.width", 250, "display.max_columns", 40):
        print(table.T.to_string(float_format=lambda x: f"{x:.3g}"))


if __name__ == "__main__":
    main()
