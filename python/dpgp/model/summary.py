"""A fitted model's summary as text (:meth:`dpgp.DPGP.summary`; ``dpgp info`` prints it): data,
patterns and their weights, the GP parameters, what the "auto" settings resolved to, the settings,
and for a model made from chains their convergence."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..generate.simulation import default_dt, default_roi


def summary(model: Any, top: int = 10) -> str:
    """The lines of ``model``'s summary, the ``top`` largest patterns listed."""
    f = model.frames_
    w = model.weights_
    top = min(len(w), int(top))
    lines = [
        f"training data: {len(f)} frames, {f.n_points} vehicle observations ({f.sizes.min()}-{f.sizes.max()} per frame)",
        "ROI: x [{:g}, {:g}], y [{:g}, {:g}]; dt {:g} s".format(*default_roi(model), default_dt(model)),
        f"patterns: {model.n_patterns_}; α = {model.alpha_:.4g}; log joint = {model.log_joint_:.6g}",
        f"sweeps: {model.n_iter_}" + (" (stopped early: converged)" if model.converged_ else ""),
        f"largest {top} patterns (frames, weight, length scales w_x, w_y"
        + (", noise variance x, y):" if _per_pattern(model) else "):"),
    ]
    if getattr(model, "chain_summary_", None):
        lines[-1:-1] = _chain_lines(model.chain_summary_)
    counts = np.bincount(model.labels_, minlength=model.n_patterns_)
    for k in range(top):
        wx, wy = model.length_scales_[k]
        row = f"  {k:>4}: {counts[k]:>6} frames  {w[k]:.3f}  ({wx:.3g}, {wy:.3g})"
        if _per_pattern(model):
            nx, ny = model.pattern_noise_var_[k]
            row += f"  ({nx:.3g}, {ny:.3g})"
        lines.append(row)
    if model.n_patterns_ > top:
        lines.append(f"  ... and {model.n_patterns_ - top} more")
    p = model.params_
    lines.append(
        f"GP: signal variance ({p.signal_var[0]:.4g}, {p.signal_var[1]:.4g}), noise variance ({p.noise_var[0]:.4g}, {p.noise_var[1]:.4g}), "
        f"mean ({p.mean[0]:.4g}, {p.mean[1]:.4g})"
    )
    lines.append(_count_and_position_line(model))
    r = model.defaults_
    a, b = r.length_scale_prior
    if r.noise_var_source == "per_pattern":
        n = model.noise_var_
        noise = (
            f"noise variance per pattern (frame-weighted median ({n[0]:.4g}, {n[1]:.4g}); sampled in the chain, "
            f"each from ({r.noise_var[0]:.4g}, {r.noise_var[1]:.4g}))"
        )
    elif r.noise_var_source == "sampled":  # r.noise_var is where the chain started; show its last draw
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
    return "\n".join(lines)


def _count_and_position_line(model: Any) -> str:
    """How the scores smooth φ and ψ: the pseudo-counts, or the flag of the paper's form."""
    from ..generate.distributions import HELD_OUT_PSEUDOCOUNT
    from ..generate.scenarios import distributions

    d = distributions(model)
    grid = f"{d.bins[0]}x{d.bins[1]} bins"
    if d.is_paper_form:
        return (
            f"φ, ψ: the paper's unsmoothed form ({grid}; a model file from before their smoothing), "
            f"scored smoothed by a pseudo-count of {HELD_OUT_PSEUDOCOUNT:g}"
        )
    return f"φ, ψ: smoothed by pseudo-counts {d.count_pseudocount:.3g} (counts), {d.position_pseudocount:.3g} ({grid})"


def _per_pattern(model: Any) -> bool:
    return getattr(getattr(model, "defaults_", None), "noise_var_source", None) == "per_pattern"


def _chain_lines(summary: dict[str, Any]) -> list[str]:
    """What the summary shows of a model made from chains."""
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


__all__ = ["summary"]
