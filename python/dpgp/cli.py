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

from ._constants import DEFAULT_DT, TRAIN_FRACTION
from .data.read import FORMATS
from .exceptions import DpgpError, InvalidInputError, UnorderedFramesError
from .plot import FIGURES as _PLOTS
from .plot import write_figures as write_figures  # its home before dpgp.plot


# --- input -------------------------------------------------------------------------------------
def load_frames(path: str, fmt: str = "auto", roi: Any = None, dt: float | None = None, units: str | None = None):
    """Frames from a file of any supported format (:func:`dpgp.read`)."""
    from . import read

    return read(path, fmt, roi=roi, dt=dt, units=units)  # read refuses units for a file of frames


# --- commands ----------------------------------------------------------------------------------
def _fit(args: argparse.Namespace) -> int:
    if args.scheduler is not None and args.chains is None:
        return _fit_on_scheduler(args)
    if args.chains is not None and _as_shards(args) is not None:
        return _fit_chains(args, args.data)  # every chain over the directory's shards
    frames = load_frames(args.data, args.format, args.roi, args.dt, args.units)
    if args.max_frames is not None:
        frames = frames[: args.max_frames]  # a selection keeps dt and ROI for simulations
    print(f"{args.data}: {frames!r}")
    if args.chains is not None:
        return _fit_chains(args, frames)
    if args.until_converged:
        raise ValueError("--until-converged and its thresholds go with --chains N")
    model = _model_of(args)
    t = time.perf_counter()
    model.fit(frames)
    print(
        f"fitted {model.n_patterns_} patterns in {time.perf_counter() - t:.1f} s ({model.n_iter_} sweeps, α = {model.alpha_:.3g})"
    )
    model.save(args.output)
    print(f"wrote {args.output}")
    return 0


def _as_shards(args: argparse.Namespace) -> Any:
    """The manifest when ``dpgp fit``'s data are a directory of frame shards to fit as they
    were written (no framing option given), else None."""
    from .model.sharded import manifest_of

    if _framing_flags(args):
        return None
    manifest = manifest_of(args.data)
    if manifest is not None:
        print(f"{args.data}: {manifest.n_frames} frames in {manifest.n_shards} shards")
    return manifest


def _fit_chains(args: argparse.Namespace, frames: Any) -> int:
    """``dpgp fit --chains N``: independent chains (locally or on a Dask scheduler), then the
    point-estimate model, saved with the chain summary."""
    from . import fit_chains

    if args.checkpoint is not None:
        raise ValueError("--checkpoint goes with a single chain, not with --chains N")
    client = None if args.scheduler is None else _connect(args.scheduler)
    t = time.perf_counter()
    try:
        chains = fit_chains(
            frames, args.chains, client, iterations=args.iterations, until="converged" if args.until_converged else None,
            rhat=args.rhat, min_ess=args.min_ess, max_iterations=args.max_iterations, seed=args.seed,
            progress=args.progress, assignment=args.assignment, alpha=args.alpha, n_threads=args.threads or 1,
            sampler=args.sampler, init=args.init,
        )  # fmt: skip
        print(f"{chains!r} in {time.perf_counter() - t:.1f} s: {chains.stop_reason_}")
        for name, error in chains.failures_.items():
            print(f"  {name} failed: {error}")
        print(chains.summary().to_string(float_format=lambda v: f"{v:.4g}"))
        model = chains.best_model(args.loss)  # chains over shards: with the client open (it serves them)
        s = model.chain_summary_["point_estimate"]
        print(
            f"point estimate ({s['loss']}): {model.n_patterns_} patterns, posterior expected loss {s['expected_loss']:.4g}"
        )
        model.save(args.output)
    finally:
        if client is not None:
            client.close()
    print(f"wrote {args.output}")
    return 0


def _connect(address: str) -> Any:
    """A ``dask.distributed`` client of the scheduler at ``address`` (``--scheduler``)."""
    try:
        from distributed import Client
    except ImportError:
        raise DpgpError("--scheduler needs Dask: pip install 'dpgp[distributed]'") from None
    return Client(address)


def _model_of(args: argparse.Namespace) -> Any:
    """The estimator ``dpgp fit``'s options describe."""
    from . import DPGP

    return DPGP(
        iterations=args.iterations, assignment=args.assignment, seed=args.seed, alpha=args.alpha,
        n_threads=args.threads, progress=args.progress, preset=args.preset, checkpoint=args.checkpoint,
        checkpoint_every=args.checkpoint_every, sampler=args.sampler, init=args.init,
    )  # fmt: skip


def _framing_flags(args: argparse.Namespace) -> list[str]:
    """The framing options ``dpgp fit`` was given (a directory of shards is fitted as written)."""
    framing = {"--roi": args.roi, "--dt": args.dt, "--units": args.units, "--max-frames": args.max_frames}
    given = [flag for flag, value in framing.items() if value is not None]
    return given + (["--format"] if args.format not in ("auto", "frames") else [])


def _fit_on_scheduler(args: argparse.Namespace) -> int:
    """``dpgp fit DIR --scheduler ADDRESS``: one chain over a directory of frame shards, each shard
    read and served by a worker of the Dask scheduler (``DPGP.fit(DIR, client=...)``)."""
    from .model.sharded import manifest_of

    given = _framing_flags(args)
    if given or args.until_converged:
        raise ValueError(
            f"{', '.join(given) or '--until-converged'} cannot go with --scheduler without --chains: "
            "the shards are fitted as they were written"
        )
    manifest = manifest_of(args.data)  # before connecting
    if manifest is None:
        raise InvalidInputError(
            f"--scheduler without --chains fits a directory of frame shards, and {args.data} is not one: write "
            "the frames as shards first (Frames.to_parquet(DIR, shards=n) or make_frames(..., out=DIR, shards=n)) "
            "and pass DIR"
        )
    print(f"{args.data}: {manifest.n_frames} frames in {manifest.n_shards} shards")
    client = _connect(args.scheduler)
    try:
        model = _model_of(args)
        t = time.perf_counter()
        model.fit(args.data, client=client)
        print(
            f"fitted {model.n_patterns_} patterns over {manifest.n_shards} shards on {args.scheduler} "
            f"in {time.perf_counter() - t:.1f} s ({model.n_iter_} sweeps, α = {model.alpha_:.3g})"
        )
        model.save(args.output)  # with the client open: the model file's parts may ask the shards
    finally:
        client.close()
    print(f"wrote {args.output}")
    return 0


def _resume(args: argparse.Namespace) -> int:
    """``dpgp resume CHECKPOINT``: continue a fit's chain from its checkpoint."""
    from . import DPGP

    client = None if args.scheduler is None else _connect(args.scheduler)
    try:
        t = time.perf_counter()
        model = DPGP.resume(args.checkpoint, iterations=args.iterations, progress=args.progress, client=client)
        print(
            f"resumed {args.checkpoint} at sweep {model.resumed_from_}: {model.n_patterns_} patterns after "
            f"{model.n_iter_} sweeps in {time.perf_counter() - t:.1f} s (α = {model.alpha_:.3g})"
        )
        if args.output is not None:
            model.save(args.output)  # with the client open: a fit over shards gathers its frames
            print(f"wrote {args.output}")
        else:
            print(f"the model is in {args.checkpoint} (a model file: dpgp info, plot and simulate read it)")
    finally:
        if client is not None:
            client.close()
    return 0


def _info(args: argparse.Namespace) -> int:
    from . import DPGP
    from .io.modelfile import read_metadata

    meta = read_metadata(args.model)
    model = DPGP.load(args.model)
    print(
        f"{args.model}: {meta['format']} format {meta['format_version']}, written by dpgp {meta.get('dpgp_version', '?')}"
    )
    print(model.summary(top=args.top))
    try:  # pattern dynamics (issue 20), for frames with times
        print(model.transitions_.summary())
    except UnorderedFramesError as e:
        print(f"transitions: none ({e})")
    return 0


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
    if args.duration is not None:
        if args.place_ego:
            raise InvalidInputError(
                "--place-ego applies to scenarios of --steps; in long scenarios (--duration) the ego is the first "
                "vehicle to come to --ego X Y [HEADING]"
            )
        return _generate_long(model, args)
    if args.phases is not None:
        raise InvalidInputError("--phases applies to long scenarios: give --duration too")
    if args.cycle:
        raise InvalidInputError("--cycle applies to long scenarios by phases: give --duration and --phases too")
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
    if args.place_ego:
        from .generate.scenarios import Ego

        if args.ego is None or len(args.ego) not in (2, 3):
            raise InvalidInputError("--place-ego places the ego at --ego X Y [HEADING]: give --ego too")
        heading = args.ego[2] if len(args.ego) == 3 else None
        args.ego = Ego(args.ego[0], args.ego[1], heading, placed=True)
    if args.critical is not None:
        if args.pattern is not None or args.dynamics not in (None, "interactive") or args.mean:
            raise InvalidInputError("--critical tilts the default generator: drop --pattern, --dynamics and --mean")
        scen = model.sample_critical(args.n, args.critical, steps=args.steps, seed=args.seed, ego=args.ego)
    else:
        scen = model.sample_scenarios(
            args.n, steps=args.steps, pattern=args.pattern, seed=args.seed, dt=args.dt, method=args.method,
            stochastic=not args.mean, dynamics=args.dynamics, ego=args.ego,
        )  # fmt: skip
    if args.critical is not None:
        _write_critical(scen, args)
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


def _write_critical(scen: Any, args: argparse.Namespace) -> None:
    """``generate --critical``: a table of every scenario's weight, starting frame and measures
    beside the output (``DIR/critical.csv`` for a directory, else ``NAME.critical.csv``), and the
    event's estimated natural rate."""
    import numpy as np
    import pandas as pd

    from .generate.criticality import Event, criticality

    event = Event.parse(args.critical, ego=args.ego is not None)
    per = criticality(scen, ego=True if event.ego else None).per_scene()
    table = pd.DataFrame({"scenario": np.arange(len(scen)), "weight": scen.weights, "source_frame": scen.sources,
                          **per, "event": event.happened(per)})  # fmt: skip
    out = Path(args.output)
    path = out / "critical.csv" if out.is_dir() or out.suffix == "" else out.with_name(out.stem + ".critical.csv")
    path.parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(path, index=False, float_format="%.17g")
    print(scen.estimate(event, measures=per))
    print(f"wrote {path}")


def _generate_long(model: Any, args: argparse.Namespace) -> int:
    """``generate --duration``: long scenarios that switch pattern (or phase) over time, as CSV."""
    import pandas as pd

    if args.format not in (None, "csv") or not args.output.lower().endswith(".csv"):
        raise InvalidInputError("long scenarios (--duration) are written as CSV: give an output path ending in .csv")
    phases: Any = args.phases
    if phases is not None and phases != "auto":
        try:
            phases = int(phases)
        except ValueError:
            raise InvalidInputError(f"--phases must be a number of phases or 'auto', got {args.phases!r}") from None
    if args.cycle:
        if phases is None:
            raise InvalidInputError("--cycle needs --phases: the number of stages in the cycle")
        # a fixed-time signal's stages: in their order, with durations, from what frames say of every pattern
        phases = model.phases(phases, durations=True, evidence="likelihood", cycle=True)
    if args.no_stop_lines and phases is None:
        raise InvalidInputError("--no-stop-lines applies to long scenarios by phases: give --phases too")
    scen = model.sample_scenarios(
        args.n, duration=args.duration, seed=args.seed, stochastic=not args.mean, dynamics=args.dynamics or True,
        phases=phases, stop_lines=not args.no_stop_lines, free_speeds=not args.no_stop_lines, ego=args.ego,
    )  # fmt: skip
    if phases is not None and not args.no_stop_lines:
        lines = model.stop_lines(phases)
        print(
            f"{len(lines)} stop line(s) learned from the recorded queues, {int(lines.red.any(axis=0).sum())} red in some phase"
        )
    out = pd.concat([sc.to_pandas().assign(scenario=i) for i, sc in enumerate(scen)], ignore_index=True)
    if args.ego is not None:  # a scenario without an ego has no column of its own
        out["ego"] = out["ego"].fillna(False).astype(bool) if "ego" in out else False
    cols = ["scenario", "vehicle", "t", "x", "y", "vx", "vy", "pattern"] + [c for c in ("phase", "ego") if c in out]
    from .io._atomic import write_atomic

    write_atomic(args.output, lambda fh: out[cols].to_csv(fh, index=False))
    switches = sum(sc.switches() for sc in scen)
    print(f"{len(scen)} long scenario(s) of {args.duration:g} s, {len(out)} vehicle-steps, {switches} pattern switches")
    if args.ego is not None:
        found = sum(sc.ego >= 0 for sc in scen)
        print(f"an ego vehicle (the first to come to the point) in {found} of {len(scen)} scenario(s): column ego")
    print(f"wrote {args.output}")
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    from . import DPGP, make_frames
    from .data.read import detect_format, read_trajectories
    from .evaluate.scores import split_in_time

    model = DPGP.load(args.model)
    summary = getattr(model.frames_, "summary", None)
    dt = args.dt if args.dt is not None else getattr(summary, "dt", None)
    roi = args.roi if args.roi is not None else getattr(summary, "roi", None)
    fmt = detect_format(args.data) if args.format == "auto" else args.format
    tracks = None if fmt == "frames" else read_trajectories(args.data, fmt)  # kept for the rollouts
    if tracks is None:
        frames = load_frames(args.data, fmt, roi, dt)
    else:  # framed like the training data
        units = getattr(summary, "units", None)
        frames = make_frames(tracks, roi=roi, dt=DEFAULT_DT if dt is None else dt, units=units)
    test = frames if args.split == 0 else split_in_time(frames, args.split)[1]
    print(
        f"{args.data}: {len(test)} test frames ({test.n_points} vehicles)"
        + (f", the last {1 - args.split:.0%}" if args.split else "")
    )
    ev = model.evaluate(test, tracks=tracks, horizons=args.horizons, agent=args.agent)
    print(ev.summary())  # the table, dpgp's margins over the baselines, why a baseline was not scored
    if ev.realism is not None:
        print("realism (WOSAC-style, dpgp.realism):")
        print(ev.realism.table.to_string(float_format=lambda x: f"{x:.3f}", na_rep=""))
        if args.realism_plot:
            ev.realism.plot().savefig(args.realism_plot, dpi=100)
            print(f"wrote {args.realism_plot}")
    from .generate.criticality import compare

    crit = compare(model, test)
    print("criticality (dpgp.generate.criticality; per scene of 16 steps: recorded windows, generated scenes):")
    print(crit.to_string(float_format=lambda x: f"{x:.3f}"))
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
    p.add_argument("--format", choices=("auto", *FORMATS), default="auto",
                   help="input kind: 'frames' (already framed), 'tracks' (any trajectory table), 'ngsim', or a "
                   "read_tracks preset; 'auto' decides from the file name and header")  # fmt: skip
    p.add_argument("--roi", nargs=4, type=_roi, metavar=("X_MIN", "X_MAX", "Y_MIN", "Y_MAX"),
                   help="region of interest; vehicles outside it are dropped (default: keep all)")  # fmt: skip
    p.add_argument(
        "--dt", type=float, help=f"time step in seconds between frames (default {DEFAULT_DT:g} for trajectories)"
    )
    p.add_argument("--units", help="convert trajectory units, e.g. 'ft->m' for NGSIM (default: keep)")
    p.add_argument("--iterations", type=int, default=100, help="Gibbs sweeps after the initialisation")
    p.add_argument("--assignment", default="gibbs",  # no choices: the core checks the name
                   help="'gibbs' samples each frame's pattern; 'map' takes the most probable (the paper's)")  # fmt: skip
    p.add_argument("--preset", choices=("paper",),
                   help="'paper': the paper's Gamma(10, 1) length scales, noise variance 1 and map assignment "
                   "(for data in feet; the default settings scale with the data)")  # fmt: skip
    p.add_argument("--sampler", default="auto",  # no choices: the estimator checks the name
                   help="'subcluster': every frame in parallel with sub-pattern split-merge moves (hsgp); "
                   "'collapsed': the paper's one frame at a time; 'auto' (default): subcluster where it runs")  # fmt: skip
    p.add_argument("--init", default="sequential",
                   help="where the chain starts: 'sequential' (default), 'one' pattern, 'many' patterns; "
                   "with --chains also 'dispersed' (chains from one and from many)")  # fmt: skip
    p.add_argument("--alpha", type=float, help="fix the DP concentration (default: sampled)")
    p.add_argument("--max-frames", type=int, help="use only the first N frames")
    p.add_argument("--threads", type=int, help="worker threads (default: all cores)")
    p.add_argument("--seed", type=int, default=0, help="random seed; a fit is a function of data, settings and seed")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=True, help="show a progress bar")
    p.add_argument("--checkpoint", metavar="PATH",
                   help="write the chain's state to PATH as it runs ('dpgp resume PATH' continues a fit that was "
                   "killed); PATH is also a model file")  # fmt: skip
    p.add_argument("--checkpoint-every", type=int, default=10, metavar="N", help="sweeps between checkpoints")
    g = p.add_argument_group("many chains (dpgp.fit_chains) and clusters")
    g.add_argument("--chains", type=int, metavar="N",
                   help="run N independent chains and save the point-estimate model with R̂ and ESS")  # fmt: skip
    g.add_argument("--scheduler", metavar="ADDRESS",
                   help="a Dask scheduler (e.g. tcp://host:8786; needs dpgp[distributed]). With --chains: run "
                   "the chains there (default: local worker processes). Without: DATA is a directory of frame "
                   "shards (Frames.to_parquet) and one chain runs over them, each shard served by a worker")  # fmt: skip
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
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="a checkpoint of a fit over shards: continue on this Dask scheduler's workers")  # fmt: skip
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
    p.add_argument(
        "--dt", type=float, help=f"time step in seconds (default: the training frames', else {DEFAULT_DT:g})"
    )
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
    p.add_argument(
        "--dt", type=float, help=f"time step in seconds (default: the training frames', else {DEFAULT_DT:g})"
    )
    p.add_argument("--method", choices=("euler", "rk4"), default="euler", help="integration scheme")
    p.add_argument(
        "--dynamics",
        choices=("interactive", "relaxed", "field"),
        default=None,
        help="interactive (default; field with --method rk4), relaxed, or field (the paper's rollout)",
    )
    p.add_argument("--mean", action="store_true", help="follow the posterior mean instead of drawing velocities")
    p.add_argument("--critical", metavar="EVENT",
                   help="draw the scenarios toward an event ('ttc<1.0', 'gap<0.5', 'pet<1', 'deceleration>4', "
                   "'collision'; with --ego, against the ego) with their likelihood ratios; writes a table of "
                   "weights and measures beside the output and prints the event's natural rate")  # fmt: skip
    p.add_argument("--ego", type=float, nargs="+", metavar="X Y [HEADING]",
                   help="each scenario's vehicle nearest (X, Y) at the start (heading within 45 degrees of HEADING, "
                   "degrees, if given) is its ego vehicle: Ego in OpenSCENARIO, s<scenario>_ego in SUMO; in long "
                   "scenarios (--duration), the first vehicle to come within a lane's width of (X, Y): column ego")  # fmt: skip
    p.add_argument("--place-ego", action="store_true",
                   help="with --ego: place the ego at (X, Y) in every scenario (heading HEADING over heading fields) "
                   "instead of choosing the nearest recorded vehicle")  # fmt: skip
    p.add_argument("--seed", type=int, help="random seed (default: random)")
    p.add_argument("--duration", type=float, help="long scenarios of this many seconds that switch pattern over time "
                   "by the learned transitions (CSV with the pattern in force; needs frames with times)")  # fmt: skip
    p.add_argument("--phases", help="with --duration: switch by phases (a number of phases, or 'auto')")
    p.add_argument("--cycle", action="store_true", help="with --phases: the phases are the stages of a fixed cycle (a "
                   "fixed-time signal), fitted with their durations to each frame's likelihood under every pattern")  # fmt: skip
    p.add_argument("--no-stop-lines", action="store_true", help="with --phases: vehicles neither stop at the stop "
                   "lines learned from the recorded queues nor drive at the recorded free speeds (the fields' "
                   "speeds instead)")  # fmt: skip
    p.set_defaults(func=_generate)

    p = sub.add_parser("evaluate", help="score a model on held-out data against baselines", formatter_class=fmt,
                       description="Held-out log density of the velocities per vehicle for the model, a single GP, "
                       "a position-blind Gaussian and, for trajectory input, a constant-velocity Gaussian around "
                       "each vehicle's previous velocity (all fitted to the model's training frames), with the "
                       "model's margin over each; for trajectory input, also rollout ADE/FDE against constant velocity and the WOSAC-style realism of generated "
                       "scenarios (dpgp.realism). DATA is framed like the training "
                       "data (its dt, ROI and units).")  # fmt: skip
    p.add_argument("model", help="model file written by 'dpgp fit'")
    p.add_argument("data", help="the data: framed table, trajectories or SUMO FCD XML")
    p.add_argument("--format", choices=("auto", *FORMATS), default="auto", help="input kind, as for 'dpgp fit'")
    p.add_argument("--split", type=float, default=TRAIN_FRACTION,
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
