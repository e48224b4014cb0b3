"""How realistic are generated scenarios? A WOSAC-style score against recorded ones (issue 15).

The Waymo Open Sim Agents Challenge (WOSAC) scores a generator by how likely the *recorded*
behaviour is under the distribution of the *generated* behaviour, feature by feature. This is
its meta-metric restricted to the features that need no map, on scenario tables
``scenario, vehicle, t, x, y`` (what :meth:`dpgp.scenarios.Scenarios.to_pandas` returns; extra
columns are ignored).

**Features**, per object step (an object's row at one time of one scenario), from positions:

========================  ====================================================  ======
feature                   definition                                            weight
========================  ====================================================  ======
``speed``                 ``|p(t + dt) - p(t)| / dt``                           0.05
``acceleration``          change of speed per time                              0.05
``turn_rate``             change of heading per time, wrapped to (-π, π]        0.05
``angular_acceleration``  change of turn rate per time                          0.05
``nearest_distance``      centre-to-centre distance to the nearest other        0.10
                          object in the scenario at the same time
``collision``             ``nearest_distance`` below :data:`COLLISION_DISTANCE`  0.25
                          (2 m for vehicles, 0.3 m for pedestrians)
``count``                 objects per scenario and time (per frame)             0.10
``position``              the 2-D position                                      0.10
========================  ====================================================  ======

Kinematics come from positions, not from the tables' velocity columns, so that every source
(recordings, dpgp, the blind generator) is measured the same way. An object's step has a speed
when it is also present one step later, and so on. Heading is the direction of motion; it is
undefined below :data:`MIN_HEADING_SPEED` (0.5 m/s: a standing object's direction is noise), and
there is then no turn rate. An object alone in its scenario at a time has no nearest distance
and does not collide.

**Score** of a feature: the generated values are histogrammed on bins fixed from the recorded
*training* data (:data:`DEFAULT_BINS` equal bins between its 0.5th and 99.5th percentiles, values
beyond going to the end bins; positions on a 20 × 20 grid over the training range; counts one
bin per integer between the training minimum and maximum), plus a pseudocount of
:data:`PSEUDOCOUNT` (0.1) in every bin; the score is ``exp(mean log P(bin of each recorded
value))``, averaged over all recorded object steps (WOSAC averages per scenario first; here the
generated scenarios are not paired with recorded ones, so the values are pooled). ``collision``
is a Bernoulli: ``P(collide) = (collisions + 0.1) / (steps + 0.2)``, the same pseudocount in
each of its two outcomes. The **meta-score** is the weighted mean of the feature scores (the
weights above, divided by their sum, 0.75; a feature without recorded values is left out).

**References**: the training period's own recorded tracks cut into windows like the generated
scenarios (recorded against recorded: what perfect realism scores, short of sampling noise), and
the **position-blind generator** (:func:`position_blind_scenarios`). The realism ratio is
``(dpgp - blind) / (recorded - blind)`` of the meta-scores: 1 matches recorded data, 0 is no
better than ignoring position, negative is worse.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from .._constants import FT_TO_M
from ..data.frames import Frames
from ..exceptions import DataFormatError, InvalidInputError, ShapeError

if TYPE_CHECKING:
    import pandas as pd
    from matplotlib.figure import Figure

#: Feature weights of the meta-score (issue 15; WOSAC's, without the map features).
WEIGHTS = {
    "speed": 0.05,
    "acceleration": 0.05,
    "turn_rate": 0.05,
    "angular_acceleration": 0.05,
    "nearest_distance": 0.10,
    "collision": 0.25,
    "count": 0.10,
    "position": 0.10,
}
FEATURES = tuple(WEIGHTS)
#: Centre-to-centre distance (metres) below which an object step counts as a collision.
COLLISION_DISTANCE = {"vehicle": 2.0, "pedestrian": 0.3}
MIN_HEADING_SPEED = 0.5  # m/s: slower than this, the direction of motion is not a heading
PSEUDOCOUNT = 0.1  # added to every bin of a generated histogram
DEFAULT_BINS = 20  # bins of a 1-D feature; the position grid is DEFAULT_BINS x DEFAULT_BINS
QUANTILES = (0.005, 0.995)  # the bin range of a 1-D feature, in quantiles of the training values
SCENARIO_SECONDS = 4.0  # length of the scenarios model.evaluate generates and compares
_UNITS = {
    "m": 1.0,
    "metre": 1.0,
    "meter": 1.0,
    "metres": 1.0,
    "meters": 1.0,
    "ft": FT_TO_M,
    "feet": FT_TO_M,
    "foot": FT_TO_M,
}
_KINEMATIC = ("speed", "acceleration", "turn_rate", "angular_acceleration")


# --- features ----------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Features:
    """The feature values of one table: ``values[name]`` is 1-D (``position``: ``(n, 2)``;
    ``collision``: booleans), one entry per object step where the feature is defined (``count``:
    per scenario and time). ``dt``: the time step the kinematics used."""

    values: dict[str, np.ndarray]
    dt: float
    collision_distance: float

    @property
    def collision_rate(self) -> float:
        c = self.values["collision"]
        return float(c.mean()) if len(c) else float("nan")


def length_scale(units: Any) -> float:
    """Metres per length unit of the data: ``"m"`` (1) or ``"ft"`` (0.3048), or a number."""
    if isinstance(units, (int, float, np.integer, np.floating)) and not isinstance(units, (bool, np.bool_)):
        if np.isfinite(units) and units > 0:
            return float(units)
    elif isinstance(units, str) and units.lower() in _UNITS:
        return _UNITS[units.lower()]
    raise InvalidInputError(f"units must be 'm', 'ft' or the metres per data unit (a positive number), got {units!r}")


def collision_threshold(agent: str = "vehicle", units: Any = "m", collision_distance: float | None = None) -> float:
    """The collision distance in the data's units: ``collision_distance`` (metres) if given, else
    :data:`COLLISION_DISTANCE` of ``agent``, divided by the metres per data unit."""
    if collision_distance is None:
        if agent not in COLLISION_DISTANCE:
            raise InvalidInputError(f"agent must be one of {sorted(COLLISION_DISTANCE)}, got {agent!r}")
        metres = COLLISION_DISTANCE[agent]
    else:
        if isinstance(collision_distance, (bool, np.bool_)) or not isinstance(
            collision_distance, (int, float, np.integer, np.floating)
        ):
            raise InvalidInputError(f"collision_distance must be a number of metres, got {collision_distance!r}")
        metres = float(collision_distance)
        if not (np.isfinite(metres) and metres >= 0):
            raise InvalidInputError(
                f"collision_distance must be a finite number of metres >= 0, got {collision_distance!r}"
            )
    return metres / length_scale(units)


def extract_features(
    table: Any,
    *,
    agent: str = "vehicle",
    units: Any = "m",
    collision_distance: float | None = None,
    dt: float | None = None,
) -> Features:
    """The features of a scenario table (see the module docstring). ``agent`` (``"vehicle"`` or
    ``"pedestrian"``) picks the collision distance unless ``collision_distance`` (metres) is
    given; ``units``: the table's length unit, ``"m"`` or ``"ft"``. ``dt``: the time step
    (default: the smallest step between an object's consecutive times)."""
    threshold = collision_threshold(agent, units, collision_distance)
    min_speed = MIN_HEADING_SPEED / length_scale(units)
    sc, veh, t, xy = _columns(table)
    order = np.lexsort((t, veh, sc))
    sc, veh, t, xy = sc[order], veh[order], t[order], xy[order]
    same = (sc[1:] == sc[:-1]) & (veh[1:] == veh[:-1])
    if np.any(same & (t[1:] == t[:-1])):
        raise InvalidInputError("the table has an object twice at one time (repeated scenario, vehicle, t)")
    gaps = np.diff(t)[same]
    if dt is None:
        dt = float(gaps.min()) if len(gaps) else float("nan")
    elif (
        isinstance(dt, (bool, np.bool_))
        or not isinstance(dt, (int, float, np.integer, np.floating))
        or not (np.isfinite(dt) and dt > 0)
    ):
        raise InvalidInputError(f"dt must be a positive number of seconds, got {dt!r}")
    n = len(t)
    # next_ok[i]: row i + 1 is the same object one time step later
    next_ok = np.zeros(n, dtype=bool)
    if np.isfinite(dt):
        next_ok[:-1] = same & (np.abs(np.diff(t) - dt) <= 1e-6 * dt)
    step = np.full((n, 2), np.nan)
    step[:-1] = xy[1:] - xy[:-1]
    step[~next_ok] = np.nan
    speed = np.hypot(step[:, 0], step[:, 1]) / dt
    heading = np.where(speed >= min_speed, np.arctan2(step[:, 1], step[:, 0]), np.nan)
    accel = _forward(speed, next_ok, dt)
    turn = _forward(heading, next_ok, dt, wrap=True)
    ang_accel = _forward(turn, next_ok, dt)
    nearest, counts = _nearest(sc, t, xy)
    values = {
        "speed": speed,
        "acceleration": accel,
        "turn_rate": turn,
        "angular_acceleration": ang_accel,
    }
    values = {k: v[np.isfinite(v)] for k, v in values.items()}
    values["nearest_distance"] = nearest[np.isfinite(nearest)]
    values["collision"] = nearest < threshold
    values["count"] = counts.astype(np.float64)
    values["position"] = xy
    return Features(values, float(dt), float(threshold))


def _forward(a: np.ndarray, next_ok: np.ndarray, dt: float, wrap: bool = False) -> np.ndarray:
    """(a[i + 1] - a[i]) / dt where row i + 1 is the same object one step later, else NaN."""
    out = np.full(len(a), np.nan)
    d = a[1:] - a[:-1]
    if wrap:
        d = np.angle(np.exp(1j * d))  # into (-π, π]
    out[:-1] = np.where(next_ok[:-1], d / dt, np.nan)
    return out


def _nearest(sc: np.ndarray, t: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row, the distance to the nearest other row of the same scenario and time (inf when
    alone), and the number of rows per scenario and time."""
    key = np.round(t, 9)
    order = np.lexsort((key, sc))
    s, k, p = sc[order], key[order], xy[order]
    new = np.r_[True, (s[1:] != s[:-1]) | (k[1:] != k[:-1])]
    starts = np.flatnonzero(new)
    sizes = np.diff(np.r_[starts, len(s)])
    nearest = np.full(len(s), np.inf)
    # groups of one size at a time: an (groups, size, size) distance array, in bounded chunks
    for m in np.unique(sizes[sizes > 1]):
        first = starts[sizes == m]
        chunk = max(1, 4_000_000 // (m * m))
        for a in range(0, len(first), chunk):
            rows = first[a : a + chunk, None] + np.arange(m)[None, :]
            g = p[rows]  # (groups, m, 2)
            d = np.linalg.norm(g[:, :, None, :] - g[:, None, :, :], axis=-1)
            d[:, np.arange(m), np.arange(m)] = np.inf
            nearest[rows] = d.min(axis=2)
    out = np.empty_like(nearest)
    out[order] = nearest
    return out, sizes


def _columns(table: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(scenario, vehicle, t, xy) of a scenario table; ``scenario`` may be absent (one scenario)."""
    if not hasattr(table, "columns"):
        raise DataFormatError(
            f"a scenario table must be a DataFrame with columns scenario, vehicle, t, x, y; got {type(table).__name__}"
        )
    cols = [str(c) for c in table.columns]
    missing = [c for c in ("vehicle", "t", "x", "y") if c not in cols]
    if missing:
        raise DataFormatError(
            f"a scenario table needs columns scenario, vehicle, t, x, y (as Scenarios.to_pandas() returns); missing {missing}, "
            f"found {cols[:12]}"
        )
    if len(table) == 0:
        raise ShapeError("the scenario table is empty: there is nothing to score")

    def col(name: str, integer: bool = False) -> np.ndarray:
        try:
            a = np.asarray(table[name].to_numpy() if hasattr(table[name], "to_numpy") else table[name])
            if integer and a.dtype.kind not in "iub":
                _, a = np.unique(a, return_inverse=True)  # labels of any kind: their codes
            a = a.astype(np.int64 if integer else np.float64)
        except (TypeError, ValueError):
            raise DataFormatError(f"column {name!r} of the scenario table is not numeric") from None
        if not integer and not np.all(np.isfinite(a)):
            raise InvalidInputError(
                f"column {name!r} of the scenario table has NaN or infinite values; drop those rows first"
            )
        return a

    sc = col("scenario", integer=True) if "scenario" in cols else np.zeros(len(table), dtype=np.int64)
    return sc, col("vehicle", integer=True), col("t"), np.column_stack([col("x"), col("y")])


# --- bins and scores ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Bins:
    """Bin edges per feature, fixed from the recorded training data (``position``: a pair of
    x and y edges). ``collision`` has no bins (a Bernoulli)."""

    edges: dict[str, Any]

    @classmethod
    def from_features(cls, train: Features, bins: int = DEFAULT_BINS) -> Bins:
        if isinstance(bins, (bool, np.bool_)) or not isinstance(bins, (int, np.integer)) or bins < 1:
            raise InvalidInputError(f"bins must be a whole number >= 1, got {bins!r}")
        edges: dict[str, Any] = {}
        for name in ("speed", "acceleration", "turn_rate", "angular_acceleration", "nearest_distance"):
            v = train.values[name]
            lo, hi = np.quantile(v, QUANTILES) if len(v) else (0.0, 1.0)
            edges[name] = _edges(float(lo), float(hi), bins)
        c = train.values["count"]
        edges["count"] = np.arange(c.min() - 0.5, c.max() + 1.0, 1.0)  # one bin per integer
        p = train.values["position"]
        edges["position"] = (
            _edges(float(p[:, 0].min()), float(p[:, 0].max()), bins),
            _edges(float(p[:, 1].min()), float(p[:, 1].max()), bins),
        )
        return cls(edges)

    def index(self, name: str, values: np.ndarray) -> tuple[np.ndarray, int]:
        """(bin of each value, number of bins); values beyond the range go to the end bins."""
        if name == "position":
            (ix, nx), (iy, ny) = (_bin(self.edges[name][0], values[:, 0]), _bin(self.edges[name][1], values[:, 1]))
            return ix * ny + iy, nx * ny
        return _bin(self.edges[name], values)


def _edges(lo: float, hi: float, bins: int) -> np.ndarray:
    if not hi > lo:
        lo, hi = lo - 0.5, hi + 0.5
    return np.linspace(lo, hi, bins + 1)


def _bin(edges: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, int]:
    b = len(edges) - 1
    return np.clip(np.searchsorted(edges, values, side="right") - 1, 0, b - 1), b


def feature_score(name: str, generated: Features, recorded: Features, bins: Bins) -> float:
    """exp(mean log-probability of the recorded values) under the generated histogram (with
    :data:`PSEUDOCOUNT` per bin) or, for ``collision``, the generated Bernoulli. NaN when the
    recorded table has no value of the feature."""
    r = recorded.values[name]
    if len(r) == 0:
        return float("nan")
    g = generated.values[name]
    if name == "collision":
        p = (g.sum() + PSEUDOCOUNT) / (len(g) + 2 * PSEUDOCOUNT)
        return float(np.exp(np.mean(np.where(r, np.log(p), np.log1p(-p)))))
    gi, n_bins = bins.index(name, g)
    ri, _ = bins.index(name, r)
    prob = (np.bincount(gi, minlength=n_bins) + PSEUDOCOUNT) / (len(g) + PSEUDOCOUNT * n_bins)
    return float(np.exp(np.mean(np.log(prob[ri]))))


def meta_score(scores: dict[str, float], weights: dict[str, float] = WEIGHTS) -> float:
    """The weighted mean of the feature scores (features with a NaN score left out)."""
    w = np.array([weights[k] for k in scores])
    s = np.array([scores[k] for k in scores], dtype=np.float64)
    ok = np.isfinite(s) & (w > 0)
    return float((w[ok] * s[ok]).sum() / w[ok].sum()) if ok.any() else float("nan")


# --- the result --------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Realism:
    """Realism of ``generated`` (and of each reference) against the recorded scenarios.

    ``scores``: one row per feature and ``meta``, one column per scored source (``generated``,
    then the references). ``ratio``: ``(generated - blind) / (recorded - blind)`` of the
    meta-scores when both references were given, else NaN. ``features``: the
    :class:`Features` of every scored source and of ``test`` (the recorded scenarios scored
    against); ``bins``: the fixed bins."""

    scores: pd.DataFrame
    ratio: float
    features: dict[str, Features]
    bins: Bins
    weights: dict[str, float] = field(default_factory=lambda: dict(WEIGHTS))

    @property
    def meta(self) -> float:
        """The generated scenarios' meta-score."""
        return float(self.scores.loc["meta", "generated"])

    @property
    def collision_rates(self) -> dict[str, float]:
        """Share of object steps that collide, per source and for ``test`` (the recorded scenarios)."""
        return {k: f.collision_rate for k, f in self.features.items()}

    @property
    def table(self) -> pd.DataFrame:
        """Per-feature scores and the meta-score per source, with each feature's ``weight``; then
        the ``collision_rate`` of each source (a share of object steps, not a score; column
        ``test``: the recorded scenarios scored against) and the realism ``ratio``."""
        t = self.scores.copy()
        t.insert(0, "weight", [self.weights.get(k, np.nan) for k in t.index[:-1]] + [sum(self.weights.values())])
        t["test"] = np.nan
        rates = self.collision_rates
        t.loc["collision_rate"] = [np.nan] + [rates[c] for c in t.columns[1:]]
        t.loc["realism_ratio"] = np.nan
        t.loc["realism_ratio", "generated"] = self.ratio
        return t

    def plot(self, source: str = "generated") -> Figure:
        """Per-feature histograms on the fixed bins, the recorded scenarios against ``source``
        (``"generated"`` or a reference), and both position maps."""
        from matplotlib.figure import Figure

        gen, rec = self.features[source], self.features["test"]
        fig = Figure(figsize=(14.0, 10.0), layout="constrained")
        axes = fig.subplots(3, 3).ravel()
        for ax, name in zip(axes, FEATURES[:-1]):
            if name == "collision":
                shares = [rec.collision_rate, gen.collision_rate]
                bars = ax.bar(["recorded", source], shares, color=["#b0b0b0", "#1f4e99"])
                ax.bar_label(bars, fmt="%.3f")
                ax.set_ylabel(f"share of object steps closer than {gen.collision_distance:.3g} (data units)")
            else:
                edges = self.bins.edges[name]
                for f, label, style in (
                    (rec, "recorded", dict(color="#808080", alpha=0.5)),
                    (gen, source, dict(color="#1f4e99", histtype="step", lw=2)),
                ):
                    v = np.clip(f.values[name], edges[0], edges[-1])
                    ax.hist(v, bins=edges, density=True, label=label, **style)
                ax.legend(fontsize=8)
            ax.set_title(f"{name}: {self.scores.loc[name, source]:.3f}")
        ex, ey = self.bins.edges["position"]
        for ax, f, label in ((axes[7], rec, "recorded"), (axes[8], gen, source)):
            p = f.values["position"]
            ax.hist2d(np.clip(p[:, 0], ex[0], ex[-1]), np.clip(p[:, 1], ey[0], ey[-1]), bins=[ex, ey], cmap="Blues")
            ax.set_title(
                f"positions, {label}" + (f": {self.scores.loc['position', source]:.3f}" if label != "recorded" else "")
            )
            ax.set_aspect("equal", adjustable="box")
        fig.suptitle(
            f"realism of {source}: meta-score {self.scores.loc['meta', source]:.3f}"
            + (f", ratio {self.ratio:.2f}" if np.isfinite(self.ratio) else "")
        )
        return fig

    def __repr__(self) -> str:
        return f"Realism(\n{self.table.to_string(float_format=lambda x: f'{x:.3f}')}\n)"


def realism(
    generated: Any,
    recorded: Any,
    reference: dict[str, Any] | None = None,
    *,
    train: Any = None,
    agent: str = "vehicle",
    units: Any = "m",
    collision_distance: float | None = None,
    bins: int = DEFAULT_BINS,
    dt: float | None = None,
) -> Realism:
    """The WOSAC-style realism of ``generated`` scenarios against ``recorded`` ones (both scenario
    tables ``scenario, vehicle, t, x, y``; see the module docstring).

    ``reference``: other generators' tables to score the same way, by name; ``"recorded"`` (the
    training period's own tracks, :func:`recorded_windows`) and ``"blind"``
    (:func:`position_blind_scenarios`) together give the realism ratio. ``train``: the recorded
    training table that fixes the bins (default: ``reference["recorded"]``, else ``recorded``
    itself). ``agent``, ``units``, ``collision_distance``: the collision rule
    (:func:`collision_threshold`); ``dt``: the time step (default: inferred per table)."""
    import pandas as pd

    reference = {} if reference is None else reference
    if not isinstance(reference, dict):
        raise InvalidInputError(f"reference must be a dict of name -> scenario table, got {type(reference).__name__}")
    rule = dict(agent=agent, units=units, collision_distance=collision_distance, dt=dt)
    names = [str(n) for n in reference]
    if {"generated", "test"} & set(names):
        raise InvalidInputError(
            "'generated' and 'test' name the scored and the recorded tables; give the references other names"
        )
    feats = {"test": extract_features(recorded, **rule), "generated": extract_features(generated, **rule)}
    for name, table in zip(names, reference.values()):
        feats[name] = extract_features(table, **rule)
    if train is not None:
        fixed = extract_features(train, **rule)
    else:
        fixed = feats["recorded"] if "recorded" in feats else feats["test"]
    b = Bins.from_features(fixed, bins)
    cols = {}
    for s in ["generated", *names]:
        per = {k: feature_score(k, feats[s], feats["test"], b) for k in FEATURES}
        cols[s] = [*per.values(), meta_score(per)]
    scores = pd.DataFrame(cols, index=pd.Index([*FEATURES, "meta"], name="feature"))
    ratio = float("nan")
    if "recorded" in reference and "blind" in reference:
        g, r, z = (scores.loc["meta", c] for c in ("generated", "recorded", "blind"))
        ratio = float((g - z) / (r - z)) if r != z else float("nan")
    return Realism(scores, ratio, feats, b)


# --- what the generated scenarios are compared with ---------------------------------------------
def recorded_windows(
    tracks: Any,
    frames: Frames,
    steps: int,
    *,
    roi: tuple[float, float, float, float] | None = None,
    dt: float | None = None,
    units: Any = None,
) -> pd.DataFrame:
    """Recorded tracks cut into scenarios like generated ones: from each frame of ``frames`` (made
    by :func:`dpgp.make_frames` from ``tracks``), the objects inside ``roi`` at its time, followed
    for ``steps`` steps of ``dt`` while they stay inside (an object that leaves is gone, as in
    :meth:`~dpgp.scenarios.Scenarios.to_pandas`). Returns ``scenario, vehicle, t, x, y, vx, vy``
    with ``t`` from 0 and ``vehicle`` the track's code. ``dt``, ``units`` (and the smoothing)
    default to how ``frames`` were made; ``roi`` to their ROI, else their bounding box."""
    import pandas as pd

    from ..data.framing import resample_tracks

    if not isinstance(frames, Frames):
        raise ShapeError(f"frames must be dpgp.Frames, got {type(frames).__name__}")
    if isinstance(steps, (bool, np.bool_)) or not isinstance(steps, (int, np.integer)) or steps < 0:
        raise InvalidInputError(f"steps must be a whole number >= 0, got {steps!r}")
    summary = getattr(frames, "summary", None)
    dt = getattr(summary, "dt", None) if dt is None else dt
    if dt is None:
        raise InvalidInputError("these frames carry no framing summary (dpgp.make_frames sets it): pass dt")
    units = getattr(summary, "units", None) if units is None else units
    if roi is None:
        roi = getattr(summary, "roi", None) or frames.bounds()
    extra = {} if summary is None else {"smoothing": summary.smoothing, "max_gap": summary.max_gap}
    res = resample_tracks(tracks, dt=float(dt), units=units, **extra)
    k = np.rint(res["t"].to_numpy() / dt).astype(np.int64)
    _, tr = np.unique(res["track"].to_numpy(), return_inverse=True)
    scene = (
        np.unique(res["scene"].to_numpy(), return_inverse=True)[1]
        if "scene" in res.columns
        else np.zeros(len(k), np.int64)
    )
    order = np.lexsort((k, tr, scene))  # each track's rows consecutive, in time
    k, tr, scene = k[order], tr[order], scene[order]
    x, y = res["x"].to_numpy()[order], res["y"].to_numpy()[order]
    vx, vy = res["vx"].to_numpy()[order], res["vy"].to_numpy()[order]
    inside = (x >= roi[0]) & (x <= roi[1]) & (y >= roi[2]) & (y <= roi[3])
    # the frames' keys (scene code, grid step) against the rows'
    scene_codes = (
        {lab: i for i, lab in enumerate(np.unique(res["scene"].to_numpy()))} if "scene" in res.columns else None
    )
    fk = []
    for fid in frames.ids:
        if scene_codes is None:
            fk.append((0, int(round(float(fid if np.ndim(fid) == 0 else fid[-1]) / dt))))
        else:
            fk.append((scene_codes.get(fid[0], -1), int(round(float(fid[1]) / dt))))
    frame_of = {key: i for i, key in enumerate(fk)}
    starts = [j for j in np.flatnonzero(inside) if (int(scene[j]), int(k[j])) in frame_of]
    j0 = np.asarray(starts, dtype=np.int64)
    s_of = np.array([frame_of[(int(scene[j]), int(k[j]))] for j in j0], dtype=np.int64)
    offs = np.arange(steps + 1)
    j = np.minimum(j0[:, None] + offs[None, :], len(k) - 1)
    ok = (
        (j0[:, None] + offs[None, :] < len(k))
        & (tr[j] == tr[j0][:, None])
        & (k[j] == k[j0][:, None] + offs)
        & inside[j]
    )
    ok = np.cumprod(ok, axis=1).astype(bool)  # followed until the first step it is missing or outside
    rows, o = np.nonzero(ok)
    jj = j[rows, o]
    out = pd.DataFrame(
        {
            "scenario": s_of[rows],
            "vehicle": tr[jj].astype(np.int64),
            "t": np.round(o * float(dt), 9),
            "x": x[jj],
            "y": y[jj],
            "vx": vx[jj],
            "vy": vy[jj],
        }
    )
    return out.sort_values(["scenario", "t", "vehicle"], kind="stable").reset_index(drop=True)


def position_blind_scenarios(
    train: Frames,
    n: int,
    steps: int,
    dt: float,
    *,
    roi: tuple[float, float, float, float] | None = None,
    seed: int | None = None,
) -> pd.DataFrame:
    """The position-blind generator: per scenario a vehicle count drawn from the training
    frames' counts, positions drawn (independently, with replacement) from the training
    positions, velocities from one Gaussian per component fitted to the training velocities
    (independent of position), then ``steps`` steps of constant velocity; a vehicle that leaves
    ``roi`` (default: the frames' ROI, else their bounding box) is gone. Seeded by ``seed``.
    Returns ``scenario, vehicle, t, x, y, vx, vy`` like :meth:`Scenarios.to_pandas`."""
    import pandas as pd

    if not isinstance(train, Frames):
        raise ShapeError(f"train must be dpgp.Frames, got {type(train).__name__}")
    for name, value in (("n", n), ("steps", steps)):
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 0:
            raise InvalidInputError(f"{name} must be a whole number >= 0, got {value!r}")
    if (
        isinstance(dt, (bool, np.bool_))
        or not isinstance(dt, (int, float, np.integer, np.floating))
        or not (np.isfinite(dt) and dt > 0)
    ):
        raise InvalidInputError(f"dt must be a positive number of seconds, got {dt!r}")
    if seed is not None and (isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0):
        raise InvalidInputError(f"seed must be a whole number >= 0 or None, got {seed!r}")
    if roi is None:
        roi = getattr(getattr(train, "summary", None), "roi", None) or train.bounds()
    rng = np.random.default_rng(seed)
    counts = rng.choice(train.sizes, size=n)
    total = int(counts.sum())
    p0 = train.xy[rng.integers(0, train.n_points, size=total)]
    v = rng.normal(train.v.mean(axis=0), train.v.std(axis=0), size=(total, 2))
    offs = np.arange(steps + 1)
    p = p0[:, None, :] + offs[None, :, None] * float(dt) * v[:, None, :]  # (vehicles, steps + 1, 2)
    inside = (p[..., 0] >= roi[0]) & (p[..., 0] <= roi[1]) & (p[..., 1] >= roi[2]) & (p[..., 1] <= roi[3])
    inside = np.cumprod(inside, axis=1).astype(bool)
    veh, o = np.nonzero(inside)
    scenario = np.repeat(np.arange(n, dtype=np.int64), counts)
    first = np.r_[0, np.cumsum(counts)[:-1]] if n else np.zeros(0, np.int64)
    vehicle = np.arange(total, dtype=np.int64) - np.repeat(first, counts)
    out = pd.DataFrame(
        {
            "scenario": scenario[veh],
            "vehicle": vehicle[veh],
            "t": o * float(dt),
            "x": p[veh, o, 0],
            "y": p[veh, o, 1],
            "vx": v[veh, 0],
            "vy": v[veh, 1],
        }
    )
    return out.sort_values(["scenario", "t", "vehicle"], kind="stable").reset_index(drop=True)


def data_units(tracks: Any, frames: Frames | None = None) -> str | None:
    """``"m"`` or ``"ft"``: the length unit of frames made from ``tracks`` (the reader's unit,
    after ``make_frames``' ``units`` conversion), or None when it cannot be told."""
    source = (getattr(tracks, "attrs", None) or {}).get("dpgp", {}).get("units")
    conv = getattr(getattr(frames, "summary", None), "units", None)
    if isinstance(conv, str) and "->" in conv:
        target = conv.split("->")[1].strip()
        return {"m": "m", "metres": "m", "meters": "m", "ft": "ft"}.get(target)
    if conv is not None:  # a bare factor: the unit is no longer known
        return None
    return source if source in ("m", "ft") else None


def data_agent(tracks: Any) -> str:
    """``"pedestrian"`` for the ETH/UCY pedestrian format, else ``"vehicle"``."""
    fmt = (getattr(tracks, "attrs", None) or {}).get("dpgp", {}).get("format")
    return "pedestrian" if fmt == "eth_ucy" else "vehicle"


def model_realism(
    model: Any,
    test_frames: Frames,
    tracks: Any,
    *,
    seconds: float = SCENARIO_SECONDS,
    seed: int | None = 0,
    agent: str | None = None,
    units: Any = None,
) -> Realism:
    """The realism protocol of issue 15 for a fitted model: as many scenarios as test frames,
    ``seconds`` long at the model's time step, from :meth:`DPGP.sample_scenarios` (seeded by
    ``seed``), scored against the test period's recorded windows, with the training period's
    windows and the position-blind generator (same count, same seed) as references, on bins
    fixed from the training windows. ``agent`` and ``units`` default to what the tracks say
    (:func:`data_agent`, :func:`data_units`; metres when unknown)."""
    from ..generate.simulation import default_dt, default_roi

    if (
        isinstance(seconds, (bool, np.bool_))
        or not isinstance(seconds, (int, float, np.integer, np.floating))
        or not (np.isfinite(seconds) and seconds > 0)
    ):
        raise InvalidInputError(f"seconds must be a positive number, got {seconds!r}")
    dt = default_dt(model)
    steps = max(1, int(round(seconds / dt)))
    roi = default_roi(model)
    n = len(test_frames)
    generated = model.sample_scenarios(n, steps=steps, seed=seed).to_pandas()
    train = model.frames_
    conv = getattr(getattr(test_frames, "summary", None), "units", None)  # both periods framed like the test one
    reference = {
        "recorded": recorded_windows(tracks, train, steps, roi=roi, dt=dt, units=conv),
        "blind": position_blind_scenarios(train, n, steps, dt, roi=roi, seed=seed),
    }
    test = recorded_windows(tracks, test_frames, steps, roi=roi, dt=dt, units=conv)
    units = units if units is not None else (data_units(tracks, test_frames) or "m")
    return realism(generated, test, reference, agent=agent or data_agent(tracks), units=units, dt=dt)


__all__ = [
    "Realism",
    "Features",
    "Bins",
    "realism",
    "extract_features",
    "feature_score",
    "meta_score",
    "collision_threshold",
    "recorded_windows",
    "position_blind_scenarios",
    "model_realism",
    "WEIGHTS",
    "FEATURES",
    "COLLISION_DISTANCE",
    "PSEUDOCOUNT",
]
