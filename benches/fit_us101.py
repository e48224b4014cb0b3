"""Fit dpgp.DPGP to the paper's highway data (NGSIM US-101, 1000 frames) and time it against a
straightforward numpy collapsed-Gibbs sweep.

    python benches/fit_us101.py --iterations 10                # dpgp fit, then the numpy sweep
    python benches/fit_us101.py --frames 200 --assignment map
    python benches/fit_us101.py --skip-dpgp --baseline-frames 20   # numpy sweep only

Prints for dpgp: median seconds per sweep (history_["seconds"]), K, the mixture proportions
(top 10), and ``m.timings_`` if the model has it. Then one numpy sweep over the same frames,
starting from dpgp's labels, length scales and α: for every frame, the frame leaves its pattern,
is scored against every pattern by the exact GP predictive (kernel + scipy ``cho_factor`` per
(frame, pattern) pair and per output, nothing cached), and against a new pattern by Algorithm 8
with ``--aux`` prior draws of the length scales (signal variances and means: the data's, as
dpgp's defaults). A full numpy sweep over 1000 frames takes many minutes, so only the first
``--baseline-frames`` frames of the sweep are timed, against the full state, and the time is
scaled by N / baseline-frames (every frame costs about the same: it is scored against all
patterns, whose sizes barely change). Without dpgp (``--skip-dpgp`` or before DPGP exists) the
numpy sweep starts from frames dealt round-robin into ``--init-patterns`` patterns.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from scipy.linalg import cho_factor, cho_solve  # noqa: E402
from scipy.special import logsumexp  # noqa: E402

import dpgp  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "ngsim_us101_frames.tsv"
LOG2PI = np.log(2 * np.pi)


# --- the numpy baseline ---------------------------------------------------------------------------
def corr(a: np.ndarray, b: np.ndarray, w) -> np.ndarray:
    dx = a[:, None, 0] - b[None, :, 0]
    dy = a[:, None, 1] - b[None, :, 1]
    return np.exp(-(dx**2) / (2 * w[0] ** 2) - dy**2 / (2 * w[1] ** 2))


def mvn_logpdf(r: np.ndarray, cov: np.ndarray) -> float:
    c = cho_factor(cov, lower=True, check_finite=False)
    return float(-0.5 * r @ cho_solve(c, r, check_finite=False) - np.sum(np.log(np.diag(c[0]))) - 0.5 * len(r) * LOG2PI)


def log_prior_lik(xy, v, w, s2, sn2, mu) -> float:
    """log N(V; μ, σ² R(w) + σ_n² I), both outputs: a frame under a pattern with no data."""
    R = corr(xy, xy, w)
    eye = np.eye(len(xy))
    return sum(mvn_logpdf(v[:, d] - mu[d], s2[d] * R + sn2 * eye) for d in range(2))


def log_predictive(train_xy, train_v, xy, v, w, s2, sn2, mu) -> float:
    """log p(V_i | D_k): exact GP predictive of the frame's velocities, both outputs."""
    R, Rs, Rss = corr(train_xy, train_xy, w), corr(train_xy, xy, w), corr(xy, xy, w)
    total = 0.0
    for d in range(2):
        c = cho_factor(s2[d] * R + sn2 * np.eye(len(R)), lower=True, check_finite=False)
        Ks = s2[d] * Rs
        mean = mu[d] + Ks.T @ cho_solve(c, train_v[:, d] - mu[d], check_finite=False)
        cov = s2[d] * Rss + sn2 * np.eye(len(xy)) - Ks.T @ cho_solve(c, Ks, check_finite=False)
        total += mvn_logpdf(v[:, d] - mean, cov)
    return total


def existing_scores(frames, members, ws, i, s2, sn2, mu) -> np.ndarray:
    """log n_k + log p(V_i | D_k) for every pattern k (``members[k]``: its frames, without i)."""
    rows = lambda j: np.arange(frames.offsets[j], frames.offsets[j + 1])  # noqa: E731
    xy, v = frames.xy[rows(i)], frames.v[rows(i)]
    out = np.empty(len(members))
    for k, mem in enumerate(members):
        r = np.concatenate([rows(j) for j in mem])
        out[k] = np.log(len(mem)) + log_predictive(frames.xy[r], frames.v[r], xy, v, ws[k], s2, sn2, mu)
    return out


def check_against_dpgp(m, frames, i: int = 0) -> float:
    """Largest difference between numpy's and dpgp's conditional of frame i over the existing
    patterns (both renormalised over them; "new" differs by its random auxiliary draws)."""
    labels, K = np.asarray(m.labels_), m.n_patterns_
    members = [[j for j in np.flatnonzero(labels == k) if j != i] for k in range(K)]
    keep = [k for k in range(K) if members[k]]
    u = existing_scores(
        frames,
        [members[k] for k in keep],
        np.asarray(m.length_scales_)[keep],
        i,
        np.var(frames.v, axis=0),
        1.0,
        frames.v.mean(axis=0),
    )
    got = np.asarray(m.conditional_log_probs(i))[keep]
    return float(np.max(np.abs((u - logsumexp(u)) - (got - logsumexp(got)))))


def numpy_sweep(
    frames, labels, ws, alpha, prior=(10.0, 1.0), n_aux=10, assignment="gibbs", noise_var=1.0, limit=None, seed=0
):
    """One collapsed-Gibbs sweep over frames 0..limit-1; returns (labels, ws, seconds).

    ``labels`` (N,) take the values 0..K-1, ``ws`` is (K, 2). Patterns emptied are dropped and
    the labels kept dense."""
    rng = np.random.default_rng(seed)
    s2, mu = np.var(frames.v, axis=0), frames.v.mean(axis=0)
    labels, ws = np.array(labels), [np.asarray(w, float) for w in ws]
    rows = [np.arange(frames.offsets[j], frames.offsets[j + 1]) for j in range(len(frames))]
    members = [list(np.flatnonzero(labels == k)) for k in range(len(ws))]
    t0 = time.perf_counter()
    for i in range(len(frames) if limit is None else limit):
        xy, v, k0 = frames.xy[rows[i]], frames.v[rows[i]], labels[i]
        members[k0].remove(i)
        aux = rng.gamma(prior[0], prior[1], size=(n_aux, 2))
        if not members[k0]:  # a singleton's own length scales are one of the auxiliaries
            aux[0] = ws[k0]
            del members[k0], ws[k0]
            labels[labels > k0] -= 1
        u = np.empty(len(ws) + 1)
        u[:-1] = existing_scores(frames, members, ws, i, s2, noise_var, mu)
        aux_ll = np.array([log_prior_lik(xy, v, w, s2, noise_var, mu) for w in aux])
        u[-1] = np.log(alpha) - np.log(n_aux) + logsumexp(aux_ll)
        k = int(np.argmax(u)) if assignment == "map" else int(rng.choice(len(u), p=np.exp(u - logsumexp(u))))
        if k == len(ws):
            j = (
                int(np.argmax(aux_ll))
                if assignment == "map"
                else int(rng.choice(n_aux, p=np.exp(aux_ll - logsumexp(aux_ll))))
            )
            members.append([])
            ws.append(aux[j])
        members[k].append(i)
        labels[i] = k
    return labels, np.array(ws), time.perf_counter() - t0


# --- the benchmark ----------------------------------------------------------------------------
def report_fit(m, total: float) -> float:
    secs = np.asarray(m.history_["seconds"], float)
    w = np.sort(np.asarray(m.weights_))[::-1]
    print(
        f"dpgp: {len(secs)} sweeps in {total:.2f} s; median {np.median(secs):.3f} s/sweep "
        f"(min {secs.min():.3f}, max {secs.max():.3f})"
    )
    print(f"  K = {m.n_patterns_}, alpha = {float(m.alpha_):.3g}; top-10 proportions: {np.round(w[:10], 3).tolist()}")
    print(
        f"  patterns with >= 1% of frames: {int(np.sum(w >= 0.01))}; singletons: {int(np.sum(np.bincount(m.labels_) == 1))}"
    )
    if hasattr(m, "timings_"):
        print("  timings_:", {k: (round(v, 3) if isinstance(v, float) else v) for k, v in dict(m.timings_).items()})
    return float(np.median(secs))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--iterations", type=int, default=10)
    ap.add_argument("--assignment", choices=["gibbs", "map"], default="gibbs")
    ap.add_argument("--frames", type=int, default=None, help="use only the first N frames")
    ap.add_argument("--baseline-frames", type=int, default=20, help="frames timed in the numpy sweep")
    ap.add_argument("--aux", type=int, default=10, help="Algorithm 8 prior draws in the numpy sweep")
    ap.add_argument("--init-patterns", type=int, default=50, help="numpy start without dpgp")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--skip-dpgp", action="store_true")
    ap.add_argument(
        "--length-scale-fraction",
        type=float,
        default=1.0,
        help="share of patterns whose length scales are resampled each sweep",
    )
    args = ap.parse_args()

    frames = dpgp.read_frames(args.data)
    if args.frames:
        frames = frames[: args.frames]
    N = len(frames)
    print(f"{args.data.name}: {frames!r}")

    dpgp_sweep = None
    if not args.skip_dpgp and hasattr(dpgp, "DPGP"):
        m = dpgp.DPGP(
            iterations=args.iterations,
            assignment=args.assignment,
            seed=args.seed,
            length_scale_fraction=args.length_scale_fraction,
            n_threads=args.threads,
            progress=True,
        )
        t = time.perf_counter()
        m.fit(frames)
        dpgp_sweep = report_fit(m, time.perf_counter() - t)
        labels, ws, alpha = np.asarray(m.labels_), np.asarray(m.length_scales_), float(m.alpha_)
        print(
            f"  numpy vs dpgp conditional of frame 0 over existing patterns: max |diff| "
            f"{check_against_dpgp(m, frames):.2e} nats"
        )
    else:
        print("dpgp: skipped" + ("" if hasattr(dpgp, "DPGP") else " (dpgp.DPGP does not exist yet)"))
        K = min(args.init_patterns, N)
        labels, ws, alpha = np.arange(N) % K, np.full((K, 2), 10.0), 1.0

    B = min(args.baseline_frames, N)
    _, _, sec = numpy_sweep(
        frames, labels, ws, alpha, n_aux=args.aux, assignment=args.assignment, limit=B, seed=args.seed
    )
    sweep = sec * N / B
    print(
        f"numpy: {B} of {N} frames against K = {len(ws)} patterns in {sec:.2f} s "
        f"({sec / B * 1e3:.1f} ms/frame) -> {sweep:.1f} s per sweep (scaled by N/{B})"
    )
    if dpgp_sweep:
        print(f"ratio numpy / dpgp seconds per sweep: {sweep / dpgp_sweep:.0f}x")


if __name__ == "__main__":
    main()
