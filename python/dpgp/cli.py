"""The ``dpgp`` command line: fit a model to traffic data, inspect it, plot it, simulate frames
and generate scenarios; ``dpgp demo`` runs all of it on built-in synthetic data.

Errors print one line (``dpgp: error: ...``) and exit with status 1; bad arguments exit 2.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any, NoReturn

from .exceptions import DataFormatError, DpgpError, InvalidInputError

_PRESETS = ("sumo", "highd", "ind", "interaction", "eth_ucy")
_FORMATS = ("auto", "frames", "tracks", "ngsim", *_PRESETS)
_PLOTS = ("weights", "trace", "field", "frames", "simulation", "animation")


# --- input -------------------------------------------------------------------------------------
def _sniff(path: str) -> str:
    """Guess the input format from the file name and its header."""
    lower = path.lower()
    if lower.endswith((".xml", ".xml.gz")):
        return "sumo"
    import pandas as pd

    try:
        if lower.endswith(".parquet"):
            cols = list(pd.read_parquet(path).columns)
        else:
            cols = list(pd.read_csv(path, sep=None, engine="python", nrows=5, encoding="utf-8-sig").columns)
    except Exception as e:  # noqa: BLE001 - pandas, csv, gzip, zlib and pyarrow each have their own
        raise DataFormatError(
            f"{path}: cannot read a header to detect the format ({type(e).__name__}: {e}); pass --format"
        ) from None
    names = {str(c).strip().lower() for c in cols}
    if {"vehicle_id", "frame_id", "local_x", "local_y"} <= names:
        return "ngsim"
    if "timestep_time" in names:
        return "sumo"
    track_ids = {"track", "track_id", "id", "trackid", "vehicle_id", "agent_id", "object_id", "ped_id"}
    frame_ids = {"frame", "frame_idx", "frame_id", "frameid", "frame_index"}
    if names & frame_ids and not names & track_ids:
        return "frames"
    return "tracks"


def load_frames(path: str, fmt: str = "auto", roi: Any = None, dt: float | None = None, units: str | None = None):
    """Frames from a file: already framed (``frame, x, y, vx, vy``) or trajectories to frame."""
    import numpy as np

    from . import make_frames, read_frames, read_ngsim, read_tracks
    from .data.framing import FramingSummary

    if not os.path.exists(path):
        raise FileNotFoundError(f"no such file: {path}")
    fmt = _sniff(path) if fmt == "auto" else fmt
    if fmt != "frames":
        tracks = read_ngsim(path) if fmt == "ngsim" else read_tracks(path, preset=None if fmt == "tracks" else fmt)
        return make_frames(tracks, roi=roi, dt=0.5 if dt is None else dt, units=units)
    frames = read_frames(path)
    if units is not None:
        raise InvalidInputError("--units applies to trajectories that are framed here, not to framed input")
    if roi is not None:
        x0, x1, y0, y1 = roi
        keep = (frames.xy[:, 0] >= x0) & (frames.xy[:, 0] <= x1) & (frames.xy[:, 1] >= y0) & (frames.xy[:, 1] <= y1)
        if not keep.any():
            raise InvalidInputError(f"no vehicle of {path} lies inside the ROI {tuple(roi)}")
        fid = np.repeat(frames.ids, frames.sizes)[keep]
        n_before = len(frames)
        frames = type(frames).from_arrays(fid, *frames.xy[keep].T, *frames.v[keep].T)
        dropped = n_before - len(frames)
    if roi is not None or dt is not None:
        # Record the time step and ROI so that simulations and plots of the model default to them.
        frames.summary = FramingSummary(
            dt=0.5 if dt is None else float(dt), max_gap=0.0, roi=None if roi is None else tuple(map(float, roi)),
            units=None, velocity="columns", smoothing=None, n_rows=frames.n_points, n_tracks=0, n_segments=0,
            n_gaps=0, n_gap_times=0, n_segments_between_grid_times=0, n_rows_between_grid_times=0,
            n_single_sample_segments=0, n_unsmoothed_segments=0, n_resampled=frames.n_points, n_outside_roi=0,
            n_points=frames.n_points, n_frames=len(frames), n_empty_frames=dropped if roi is not None else 0, n_scenes=1,
        )  # fmt: skip
    return frames


# --- commands ----------------------------------------------------------------------------------
def _fit(args: argparse.Namespace) -> int:
    from . import DPGP

    frames = load_frames(args.data, args.format, args.roi, args.dt, args.units)
    if args.max_frames is not None:
        frames = frames[: args.max_frames]  # a selection keeps dt and ROI for simulations
    print(f"{args.data}: {frames!r}")
    if args.chains is not None:
        return _fit_chains(args, frames)
    if args.scheduler is not None or args.until_converged:
        raise ValueError("--scheduler and --until-converged go with --chains N")
    model = DPGP(
        iterations=args.iterations, assignment=args.assignment, seed=args.seed, alpha=args.alpha,
        n_threads=args.threads, progress=args.progress, preset=args.preset, checkpoint=args.checkpoint,
        checkpoint_every=args.checkpoint_every,
    )  # fmt: skip
    t = time.perf_counter()
    model.fit(frames)
    print(
        f"fitted {model.n_patterns_} patterns in {time.perf_counter() - t:.1f} s ({model.n_iter_} sweeps, α = {model.alpha_:.3g})"
    )
    model.save(args.output)
    print(f"wrote {args.output}")
    return 0


def _fit_chains(args: argparse.Namespace, frames: Any) -> int:
    """``dpgp fit --chains N``: independent chains (locally or on a Dask scheduler), then the
    point-estimate model, saved with the chain summary."""
    from . import fit_chains

    if args.checkpoint is not None:
        raise ValueError("--checkpoint goes with a single chain, not with --chains N")
    client = None
    if args.scheduler is not None:
        try:
            from distributed import Client
        except ImportError:
            raise DpgpError("--scheduler needs Dask: pip install 'dpgp[distributed]'") from None
        client = Client(args.scheduler)
    t = time.perf_counter()
    try:
        chains = fit_chains(
            frames, args.chains, client, iterations=args.iterations, until="converged" if args.until_converged else None,
            rhat=args.rhat, min_ess=args.min_ess, max_iterations=args.max_iterations, seed=args.seed,
            progress=args.progress, assignment=args.assignment, alpha=args.alpha, n_threads=args.threads or 1,
        )  # fmt: skip
    finally:
        if client is not None:
            client.close()
    print(f"{chains!r} in {time.perf_counter() - t:.1f} s: {chains.stop_reason_}")
    for name, error in chains.failures_.items():
        print(f"  {name} failed: {error}")
    print(chains.summary().to_string(float_format=lambda v: f"{v:.4g}"))
    model = chains.best_model(args.loss)
    s = model.chain_summary_["point_estimate"]
    print(
        f"point estimate ({s['loss']}): {model.n_patterns_} patterns, posterior expected loss {s['expected_loss']:.4g}"
    )
    model.save(args.output)
    print(f"wrote {args.output}")
    return 0


def _resume(args: argparse.Namespace) -> int:
    """``dpgp resume CHECKPOINT``: continue a fit's chain from its checkpoint."""
    from . import DPGP

    t = time.perf_counter()
    model = DPGP.resume(args.checkpoint, iterations=args.iterations, progress=args.progress)
    print(
        f"resumed {args.checkpoint} at sweep {model.resumed_from_}: {model.n_patterns_} patterns after "
        f"{model.n_iter_} sweeps in {time.perf_counter() - t:.1f} s (α = {model.alpha_:.3g})"
    )
    if args.output is not None:
        model.save(args.output)
        print(f"wrote {args.output}")
    else:
        print(f"the model is in {args.checkpoint} (a model file: dpgp info, plot and simulate read it)")
    return 0


def _chain_lines(summary: dict[str, Any]) -> list[str]:
    """What ``dpgp info`` shows of a model made from chains."""
    names = {"log_joint": "log joint", "n_patterns": "K", "alpha": "α"}

    def row(key: str, fmt: str) -> str:
        return ", ".join(f"{names.get(q, q)} {format(v, fmt)}" for q, v in summary[key].items())

    pe = summary["point_estimate"]
    lines = [
        f"chains: {summary['n_chains']} × {summary['n_sweeps']} sweeps, burn-in {summary['burn_in']}; {summary['stop_reason']}",
        f"  R̂: {row('rhat', '.4f')}",
        f"  ESS bulk: {row('ess_bulk', '.0f')}; tail: {row('ess_tail', '.0f')}",
        f"  point estimate ({pe['loss']}): {pe['n_patterns']} patterns, posterior expected loss {pe['expected_loss']:.4g}",
    ]
    lines += [f"  {name} failed: {error}" for name, error in summary.get("failures", {}).items()]
    return lines


def _info(args: argparse.Namespace) -> int:
    import numpy as np

    from . import DPGP
    from .generate.simulation import default_dt, default_roi
    from .io.modelfile import read_metadata

    meta = read_metadata(args.model)
    model = DPGP.load(args.model)
    f = model.frames_
    w = model.weights_
    top = min(len(w), args.top)
    lines = [
        f"{args.model}: {meta['format']} format {meta['format_version']}, written by dpgp {meta.get('dpgp_version', '?')}",
        f"training data: {len(f)} frames, {f.n_points} vehicle observations ({f.sizes.min()}-{f.sizes.max()} per frame)",
        "ROI: x [{:g}, {:g}], y [{:g}, {:g}]; dt {:g} s".format(*default_roi(model), default_dt(model)),
        f"patterns: {model.n_patterns_}; α = {model.alpha_:.4g}; log joint = {model.log_joint_:.6g}",
        f"sweeps: {model.n_iter_}" + (" (stopped early: converged)" if model.converged_ else ""),
        f"largest {top} patterns (frames, weight, length scales w_x, w_y):",
    ]
    if getattr(model, "chain_summary_", None):
        lines[-1:-1] = _chain_lines(model.chain_summary_)
    counts = np.bincount(model.labels_, minlength=model.n_patterns_)
    for k in range(top):
        wx, wy = model.length_scales_[k]
        lines.append(f"  {k:>4}: {counts[k]:>6} frames  {w[k]:.3f}  ({wx:.3g}, {wy:.3g})")
    if model.n_patterns_ > top:
        lines.append(f"  ... and {model.n_patterns_ - top} more")
    p = model.params_
    lines.append(
        f"GP: signal variance ({p.signal_var[0]:.4g}, {p.signal_var[1]:.4g}), noise variance ({p.noise_var[0]:.4g}, {p.noise_var[1]:.4g}), "
        f"mean ({p.mean[0]:.4g}, {p.mean[1]:.4g})"
    )
    r = model.defaults_
    a, b = r.length_scale_prior
    if r.noise_var_source == "sampled":  # r.noise_var is where the chain started; show its last draw
        n = model.noise_var_
        noise = f"noise variance ({n[0]:.4g}, {n[1]:.4g}) (sampled in the chain, from ({r.noise_var[0]:.4g}, {r.noise_var[1]:.4g}))"
    else:
        noise = f"noise variance ({r.noise_var[0]:.4g}, {r.noise_var[1]:.4g}) ({r.noise_var_source})"
    lines.append(
        f"resolved: {noise}, length-scale prior Gamma({a:g}, {b:.4g}) "
        f"({r.length_scale_prior_source}), assignment {r.assignment}"
    )
    settings = {k: v for k, v in model.get_params().items() if k not in ("progress",)}
    lines.append("settings: " + ", ".join(f"{k}={v!r}" for k, v in settings.items()))
    print("\n".join(lines))
    return 0


def write_figures(
    model, out: Path, kinds: list[str], n_patterns: int, frame: int | None, steps: int, dpi: int
) -> list[Path]:
    """Write the chosen figures of ``model`` into ``out``; returns the paths written."""
    import numpy as np

    from . import plot

    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []

    def save(fig, name: str) -> None:
        path = out / name
        fig.savefig(path, dpi=dpi)
        written.append(path)

    if frame is None:
        frame = int(np.flatnonzero(model.labels_ == 0)[0])  # a frame of the largest pattern
    ks = range(min(n_patterns, model.n_patterns_))
    if "weights" in kinds:
        save(plot.weights(model).figure, "weights.png")
    if "trace" in kinds:
        save(plot.trace(model), "trace.png")
    for k in ks:
        if "field" in kinds:
            save(plot.velocity_field(model, k).figure, f"field_{k}.png")
        if "frames" in kinds:
            save(plot.frames(model, k).figure, f"frames_{k}.png")
    if "simulation" in kinds or "animation" in kinds:
        sim = model.simulate(frame, steps=steps)
        if "simulation" in kinds:
            save(plot.simulation(model, frame, result=sim).figure, "simulation.png")
        if "animation" in kinds:
            path = out / "simulation.gif"
            plot.animate(sim, path, model=model)
            written.append(path)
    return written


def _plot(args: argparse.Namespace) -> int:
    from . import DPGP

    model = DPGP.load(args.model)
    kinds = list(_PLOTS) if "all" in args.kind else args.kind
    for path in write_figures(model, Path(args.out), kinds, args.patterns, args.frame, args.steps, args.dpi):
        print(f"wrote {path}")
    return 0


def _simulate(args: argparse.Namespace) -> int:
    from . import DPGP

    model = DPGP.load(args.model)
    sim = model.simulate(
        args.frame, pattern=args.pattern, steps=args.steps, dt=args.dt, method=args.method,
        stochastic=args.stochastic, seed=args.seed, dynamics=args.dynamics,
    )  # fmt: skip
    sim.to_pandas().to_csv(args.output, index=False, float_format="%.17g")
    print(sim)
    print(f"wrote {args.output}")
    return 0


def _generate(args: argparse.Namespace) -> int:
    from . import DPGP

    model = DPGP.load(args.model)
    one_file = args.output.lower().endswith(".xosc")
    xosc = args.format == "xosc" or (args.format is None and (one_file or os.path.isdir(args.output)))
    if xosc:  # checked before generating: a missing extra or a wrong path is said at once
        from .generate.openscenario import require_scenariogeneration

        require_scenariogeneration()
        if one_file and args.n != 1:
            raise InvalidInputError(f"{args.output} names one .xosc file but -n is {args.n}; give a directory")
        if args.seed is None:  # a file records its seed: draw one to record
            import secrets

            args.seed = secrets.randbelow(2**31)
    scen = model.sample_scenarios(
        args.n, steps=args.steps, pattern=args.pattern, seed=args.seed, dt=args.dt, method=args.method,
        stochastic=not args.mean, dynamics=args.dynamics,
    )  # fmt: skip
    if xosc:
        paths = scen.to_openscenario(
            args.output, model, units=args.units, origin=args.origin or (0.0, 0.0), road_network=args.road_network,
            seed=args.seed, description=f"dpgp generate {os.path.basename(args.model)}", progress=sys.stderr.isatty(),
        )  # fmt: skip
        print(scen)
        print(f"wrote {len(paths)} OpenSCENARIO file(s) to {args.output}")
        return 0
    scen.save(args.output, format=args.format)
    print(scen)
    print(f"wrote {args.output}")
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    from . import DPGP
    from .evaluate.scores import split_in_time

    model = DPGP.load(args.model)
    summary = getattr(model.frames_, "summary", None)
    dt = args.dt if args.dt is not None else getattr(summary, "dt", None)
    roi = args.roi if args.roi is not None else getattr(summary, "roi", None)
    fmt = _sniff(args.data) if args.format == "auto" else args.format
    tracks = None
    if fmt == "frames":
        frames = load_frames(args.data, fmt, roi, dt)
    else:  # trajectories: framed like the training data, and kept for the rollouts
        from . import make_frames, read_ngsim, read_tracks

        tracks = (
            read_ngsim(args.data) if fmt == "ngsim" else read_tracks(args.data, preset=None if fmt == "tracks" else fmt)
        )
        units = getattr(summary, "units", None)
        frames = make_frames(tracks, roi=roi, dt=0.5 if dt is None else dt, units=units)
    test = frames if args.split == 0 else split_in_time(frames, args.split)[1]
    print(
        f"{args.data}: {len(test)} test frames ({test.n_points} vehicles)"
        + (f", the last {1 - args.split:.0%}" if args.split else "")
    )
    ev = model.evaluate(test, tracks=tracks, horizons=args.horizons, agent=args.agent)
    print(ev.table.to_string(float_format=lambda x: f"{x:.3f}"))
    if ev.realism is not None:
        print("realism (WOSAC-style, dpgp.realism):")
        print(ev.realism.table.to_string(float_format=lambda x: f"{x:.3f}", na_rep=""))
        if args.realism_plot:
            ev.realism.plot().savefig(args.realism_plot, dpi=100)
            print(f"wrote {args.realism_plot}")
    if args.output:
        ev.table.to_csv(args.output)
        print(f"wrote {args.output}")
    if args.plot:
        ev.plot().savefig(args.plot, dpi=100)
        print(f"wrote {args.plot}")
    return 0


def _demo(args: argparse.Namespace) -> int:
    from . import DPGP, adjusted_rand_index, datasets

    t0 = time.perf_counter()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    frames = datasets.synthetic("intersection", n_frames=args.frames, seed=args.seed)
    truth = len(datasets.patterns("intersection"))
    print(f"synthetic four-way intersection: {frames!r}, {truth} true motion patterns")
    model = DPGP(iterations=args.iterations, seed=args.seed, progress=args.progress).fit(frames)
    ari = adjusted_rand_index(frames.labels, model.labels_)
    print(f"found {model.n_patterns_} patterns (true: {truth}); adjusted Rand index against the truth {ari:.3f}")
    model.save(out / "model.npz")
    print(f"wrote {out / 'model.npz'}")
    for path in write_figures(model, out, list(_PLOTS), model.n_patterns_, None, args.steps, 100):
        print(f"wrote {path}")
    print(f"done in {time.perf_counter() - t0:.1f} s")
    return 0


# --- parser ------------------------------------------------------------------------------------
class _Help(argparse.ArgumentDefaultsHelpFormatter):
    """Show a default only where it says something (not None, not already in the text)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        quiet = action.default is None or action.default is False or action.default == argparse.SUPPRESS
        if "default" in text or quiet or action.required:
            return text
        return super()._get_help_string(action) or text


class _Parser(argparse.ArgumentParser):
    """Usage errors in one line (the usage text is one ``--help`` away), exit status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())} (see {self.prog} --help)\n")


def _roi(text: str) -> float:
    return float(text)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="dpgp",
        description="Learn multi-vehicle motion patterns from traffic data (a Dirichlet-process mixture of "
        "Gaussian-process velocity fields) and use them: simulate frames, generate scenarios.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    fmt = _Help

    p = sub.add_parser("fit", help="fit a model to traffic data and save it", formatter_class=fmt,
                       description="Fit a DP-GP model to framed data (frame, x, y, vx, vy) or to trajectories, "
                       "which are framed first (resampled to --dt, cropped to --roi).")  # fmt: skip
    p.add_argument("data", help="CSV/TSV/Parquet table or SUMO FCD XML")
    p.add_argument("-o", "--output", required=True, help="model file to write (.npz)")
    p.add_argument("--format", choices=_FORMATS, default="auto",
                   help="input kind: 'frames' (already framed), 'tracks' (any trajectory table), 'ngsim', or a "
                   "read_tracks preset; 'auto' decides from the file name and header")  # fmt: skip
    p.add_argument("--roi", nargs=4, type=_roi, metavar=("X_MIN", "X_MAX", "Y_MIN", "Y_MAX"),
                   help="region of interest; vehicles outside it are dropped (default: keep all)")  # fmt: skip
    p.add_argument("--dt", type=float, help="time step in seconds between frames (default 0.5 for trajectories)")
    p.add_argument("--units", help="convert trajectory units, e.g. 'ft->m' for NGSIM (default: keep)")
    p.add_argument("--iterations", type=int, default=100, help="Gibbs sweeps after the initialisation")
    p.add_argument("--assignment", choices=("gibbs", "map"), default="gibbs",
                   help="'gibbs' samples each frame's pattern; 'map' takes the most probable (the paper's)")  # fmt: skip
    p.add_argument("--preset", choices=("paper",),
                   help="'paper': the paper's Gamma(10, 1) length scales, noise variance 1 and map assignment "
                   "(for data in feet; the default settings scale with the data)")  # fmt: skip
    p.add_argument("--alpha", type=float, help="fix the DP concentration (default: sampled)")
    p.add_argument("--max-frames", type=int, help="use only the first N frames")
    p.add_argument("--threads", type=int, help="worker threads (default: all cores)")
    p.add_argument("--seed", type=int, default=0, help="random seed; a fit is a function of data, settings and seed")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=True, help="show a progress bar")
    p.add_argument("--checkpoint", metavar="PATH",
                   help="write the chain's state to PATH as it runs ('dpgp resume PATH' continues a fit that was "
                   "killed); PATH is also a model file")  # fmt: skip
    p.add_argument("--checkpoint-every", type=int, default=10, metavar="N", help="sweeps between checkpoints")
    g = p.add_argument_group("many chains (dpgp.fit_chains)")
    g.add_argument("--chains", type=int, metavar="N",
                   help="run N independent chains and save the point-estimate model with R̂ and ESS")  # fmt: skip
    g.add_argument("--scheduler", metavar="ADDRESS",
                   help="run the chains on this Dask scheduler (e.g. tcp://host:8786; needs dpgp[distributed]); "
                   "default: local worker processes")  # fmt: skip
    g.add_argument("--until-converged", action="store_true",
                   help="advance the chains until R̂ <= --rhat and ESS >= --min-ess (at most --max-iterations "
                   "sweeps) instead of --iterations sweeps")  # fmt: skip
    g.add_argument("--rhat", type=float, default=1.01, help="R̂ threshold of --until-converged")
    g.add_argument("--min-ess", type=float, default=400, help="bulk and tail ESS threshold of --until-converged")
    g.add_argument("--max-iterations", type=int, default=2000, help="sweep cap of --until-converged")
    g.add_argument("--loss", choices=("vi", "binder"), default="vi", help="loss the point estimate minimises")
    p.set_defaults(func=_fit)

    p = sub.add_parser("resume", help="continue a fit from its checkpoint", formatter_class=fmt,
                       description="Continue the chain of a fit run with --checkpoint from the last state it wrote; "
                       "the result is bitwise that of the fit run without interruption. The fit keeps "
                       "checkpointing to the same file, which holds the final model at the end.")  # fmt: skip
    p.add_argument("checkpoint", help="checkpoint written by 'dpgp fit --checkpoint'")
    p.add_argument("--iterations", type=int,
                   help="total sweeps of the chain (default: the original fit's); more extends it")  # fmt: skip
    p.add_argument("-o", "--output", help="also write the final model here (.npz)")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=True, help="show a progress bar")
    p.set_defaults(func=_resume)

    p = sub.add_parser("info", help="summarise a model file", formatter_class=fmt,
                       description="Print what a model file holds: data, patterns, weights, settings.")  # fmt: skip
    p.add_argument("model", help="model file written by 'dpgp fit'")
    p.add_argument("--top", type=int, default=10, help="list this many of the largest patterns")
    p.set_defaults(func=_info)

    p = sub.add_parser("plot", help="write a model's figures as PNG (and a GIF)", formatter_class=fmt,
                       description="Write figures: mixture weights, Gibbs trace, velocity fields and observed "
                       "frames of the largest patterns, a simulated frame and its animation.")  # fmt: skip
    p.add_argument("model", help="model file written by 'dpgp fit'")
    p.add_argument("--out", required=True, help="directory for the figures (created if needed)")
    p.add_argument("--kind", nargs="+", choices=(*_PLOTS, "all"), default=["all"], help="which figures")
    p.add_argument("--patterns", type=int, default=3, help="field and frames figures for this many largest patterns")
    p.add_argument("--frame", type=int, help="training frame to simulate (default: one of the largest pattern)")
    p.add_argument("--steps", type=int, default=40, help="steps of the simulation")
    p.add_argument("--dpi", type=int, default=100, help="resolution of the PNG files")
    p.set_defaults(func=_plot)

    p = sub.add_parser("simulate", help="roll a frame's vehicles forward and write the trajectories", formatter_class=fmt,
                       description="Move the vehicles of a training frame through a pattern's velocity field; "
                       "write one row per step and vehicle (step, t, vehicle, x, y, vx, vy, in_roi, low_data).")  # fmt: skip
    p.add_argument("model", help="model file written by 'dpgp fit'")
    p.add_argument("--frame", type=int, required=True, help="index of the training frame (0-based)")
    p.add_argument("-o", "--output", required=True, help="CSV file to write")
    p.add_argument("--pattern", type=int, help="pattern to follow (default: the frame's own)")
    p.add_argument("--steps", type=int, default=100, help="number of time steps")
    p.add_argument("--dt", type=float, help="time step in seconds (default: the training frames', else 0.5)")
    p.add_argument("--method", choices=("euler", "rk4"), default="euler", help="integration scheme")
    p.add_argument(
        "--dynamics",
        choices=("interactive", "relaxed", "field"),
        default=None,
        help="interactive (default; field with --method rk4), relaxed, or field (the paper's rollout)",
    )
    p.add_argument("--stochastic", action="store_true", help="draw velocities from the posterior at every step")
    p.add_argument("--seed", type=int, help="seed of the stochastic draws (default: random)")
    p.set_defaults(func=_simulate)

    p = sub.add_parser("generate", help="generate new scenarios and write them as CSV or SUMO FCD", formatter_class=fmt,
                       description="Draw scenarios: a pattern by weight, a vehicle count from the data's count "
                       "distribution, positions from the pattern's data, velocities from its GP, then a rollout.")  # fmt: skip
    p.add_argument("model", help="model file written by 'dpgp fit'")
    p.add_argument("-n", type=int, required=True, help="number of scenarios")
    p.add_argument("-o", "--output", required=True, help="file to write (xosc: a directory, or a .xosc file for -n 1)")
    p.add_argument("--format", choices=("csv", "sumo", "xosc"),
                   help="'csv' (scenario, vehicle, t, x, y, vx, vy), 'sumo' (FCD XML) or 'xosc' (ASAM OpenSCENARIO 1.2, "
                   "one file per scenario; needs dpgp[openscenario]); default from the extension")  # fmt: skip
    p.add_argument("--units", choices=("m", "ft"), help="xosc: the model's position unit, if it does not record it")
    p.add_argument("--origin", type=float, nargs=2, metavar=("X", "Y"), help="xosc: subtract this point (model units)")
    p.add_argument("--road-network", help="xosc: OpenDRIVE file to reference (path written as given)")
    p.add_argument("--steps", type=int, default=100, help="number of time steps per scenario")
    p.add_argument("--pattern", type=int, help="draw every scenario from this pattern (default: by weight)")
    p.add_argument("--dt", type=float, help="time step in seconds (default: the training frames', else 0.5)")
    p.add_argument("--method", choices=("euler", "rk4"), default="euler", help="integration scheme")
    p.add_argument(
        "--dynamics",
        choices=("interactive", "relaxed", "field"),
        default=None,
        help="interactive (default; field with --method rk4), relaxed, or field (the paper's rollout)",
    )
    p.add_argument("--mean", action="store_true", help="follow the posterior mean instead of drawing velocities")
    p.add_argument("--seed", type=int, help="random seed (default: random)")
    p.set_defaults(func=_generate)

    p = sub.add_parser("evaluate", help="score a model on held-out data against baselines", formatter_class=fmt,
                       description="Held-out log density of the velocities per vehicle for the model, a single GP and "
                       "a position-blind Gaussian (both fitted to the model's training frames); for trajectory "
                       "input, also rollout ADE/FDE against constant velocity and the WOSAC-style realism of generated "
                       "scenarios (dpgp.realism). DATA is framed like the training "
                       "data (its dt, ROI and units).")  # fmt: skip
    p.add_argument("model", help="model file written by 'dpgp fit'")
    p.add_argument("data", help="the data: framed table, trajectories or SUMO FCD XML")
    p.add_argument("--format", choices=_FORMATS, default="auto", help="input kind, as for 'dpgp fit'")
    p.add_argument("--split", type=float, default=0.7,
                   help="score the frames after this share of DATA (the protocol: the model was fitted to the first "
                   "share, e.g. with --max-frames); 0 scores all of DATA")  # fmt: skip
    p.add_argument("--horizons", type=float, nargs="+", default=[1.0, 2.0, 4.0], help="rollout horizons in seconds")
    p.add_argument(
        "--roi", nargs=4, type=_roi, metavar=("X_MIN", "X_MAX", "Y_MIN", "Y_MAX"), help="default: the model's"
    )
    p.add_argument("--dt", type=float, help="time step in seconds (default: the model's)")
    p.add_argument("-o", "--output", help="write the table as CSV")
    p.add_argument("--plot", help="write the figure (PNG)")
    p.add_argument(
        "--agent",
        choices=("vehicle", "pedestrian"),
        help="realism's collision distance (2 m / 0.3 m); default: pedestrian for ETH/UCY, else vehicle",
    )
    p.add_argument("--realism-plot", help="write the realism figure, per-feature histograms (PNG)")
    p.set_defaults(func=_evaluate)

    p = sub.add_parser("demo", help="fit built-in synthetic data and write every figure", formatter_class=fmt,
                       description="Fit the synthetic four-way intersection (dpgp.datasets.synthetic) and write the "
                       "model, the paper's figures as PNG and an animated simulation as GIF into --out.")  # fmt: skip
    p.add_argument("--out", default="dpgp-demo", help="output directory")
    p.add_argument("--frames", type=int, default=200, help="number of synthetic frames")
    p.add_argument("--iterations", type=int, default=15, help="Gibbs sweeps")
    p.add_argument("--steps", type=int, default=40, help="steps of the simulated frame")
    p.add_argument("--seed", type=int, default=0, help="seed of the data and the fit")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=True, help="show a progress bar")
    p.set_defaults(func=_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as e:  # a usage error, already printed as one line; --help exits 0
        if e.code in (0, None):
            raise
        return e.code if isinstance(e.code, int) else 2
    try:
        return int(args.func(args))
    except (DpgpError, OSError, ValueError, ImportError) as e:  # ImportError: an optional extra is missing
        msg = " ".join(str(e).split()) or type(e).__name__
        print(f"dpgp: error: {msg}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("dpgp: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # a defect of dpgp: still one line for the user, never a traceback
        msg = " ".join(str(e).split())[:300]
        print(f"dpgp: internal error ({type(e).__name__}: {msg}); please report it", file=sys.stderr)
        return 3


if __name__ == "__main__":
    sys.exit(main())
