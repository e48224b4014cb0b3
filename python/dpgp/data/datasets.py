"""Synthetic traffic scenes drawn from known motion patterns, with their true labels.

For tests, the demo, and for trying the package without data::

    frames = dpgp.datasets.synthetic("highway", n_frames=200, seed=0)
    frames.labels            # the true pattern of each frame, 0..K-1
    dpgp.datasets.patterns("highway")   # names and proportions, in label order
    dpgp.datasets.roi("highway")        # (x_min, x_max, y_min, y_max)

Units are metres and metres per second. A pattern is a set of *streams*: a path through the
region of interest (ROI), a speed along it, and the share of a frame's vehicles it carries. A
frame draws its vehicle count uniformly from ``vehicles`` (inclusive), splits the vehicles over
the pattern's streams (each stream gets at least ``floor(l * share)``), puts each vehicle at a
uniform position along its stream's path (plus 0.3 m of lateral jitter), and gives it the
pattern's velocity there (speed times the path's direction) plus Gaussian noise of standard
deviation ``noise`` in each component. The velocity field of a pattern is fixed: frames of one
pattern differ only in where their vehicles are and in the noise.

``highway`` — ROI x ∈ [0, 16] across the road (x to the right of travel), y ∈ [0, 200] along it;
four 4 m lanes centred at x = 2, 6, 10, 14 (lane 0 on the left), traffic moving towards +y:

0. ``free_flow`` (50%): lanes at 32, 30, 28, 26 m/s, vehicles spread evenly over the lanes;
1. ``lane_change_left`` (25%): the right lane ends; its vehicles move one lane left between
   y = 60 and 120 m (lateral speed up to 1.8 m/s); lanes at 22, 20, 18, 18 m/s;
2. ``right_lane_queue`` (25%): a crawling exit queue in the right lane (3 m/s, 40% of the
   vehicles) beside lanes at 24, 18, 12 m/s.

``intersection`` — ROI x, y ∈ [-50, 50], a four-way signalised junction centred at the origin
(right-hand traffic): lanes 3 m either side of each road's centre line, stop lines 15 m from the
centre; queued vehicles stand still between the ROI edge and their stop line:

0. ``north_south_through`` (30%): northbound and southbound through at 12 m/s (60% of the
   vehicles), east- and westbound queued;
1. ``east_west_through`` (30%): the same turned by 90 degrees;
2. ``left_turns`` (20%): northbound and southbound turning left on 18 m arcs at 7 m/s, east-
   and westbound queued;
3. ``stop_line_queue`` (20%): every approach queued (all red).

Patterns differ by several m/s at positions they share, far more than the noise, so a correct
sampler recovers them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..exceptions import InvalidInputError
from .frames import Frames

_ROIS = {"highway": (0.0, 16.0, 0.0, 200.0), "intersection": (-50.0, 50.0, -50.0, 50.0)}


@dataclass(frozen=True)
class _Stream:
    path: np.ndarray  # (m, 2) polyline, in the direction of travel
    speed: float
    share: float


def _line(a, b) -> np.ndarray:
    return np.array([a, b], dtype=float)


def _smoothstep(t: np.ndarray) -> np.ndarray:
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3 - 2 * t)


def _highway() -> list[tuple[str, float, list[_Stream]]]:
    lanes = [2.0, 6.0, 10.0, 14.0]
    y = np.linspace(0.0, 200.0, 801)
    merge = np.column_stack([14.0 - 4.0 * _smoothstep((y - 60.0) / 60.0), y])
    straight = [_line((x, 0.0), (x, 200.0)) for x in lanes]
    return [
        ("free_flow", 0.50, [_Stream(p, s, 0.25) for p, s in zip(straight, (32, 30, 28, 26))]),
        (
            "lane_change_left",
            0.25,
            [_Stream(p, s, 0.25) for p, s in zip(straight[:3] + [merge], (22, 20, 18, 18))],
        ),
        (
            "right_lane_queue",
            0.25,
            [_Stream(p, s, w) for p, s, w in zip(straight, (24, 18, 12, 3), (0.2,) * 3 + (0.4,))],
        ),
    ]


def _intersection() -> list[tuple[str, float, list[_Stream]]]:
    L, H, a = 50.0, 15.0, 3.0  # ROI half-width, stop line distance, lane offset

    def rot(p: np.ndarray, quarter_turns: int) -> np.ndarray:
        c, s = np.round(np.cos(quarter_turns * np.pi / 2)), np.round(np.sin(quarter_turns * np.pi / 2))
        return p @ np.array([[c, s], [-s, c]])

    # Northbound, then the other approaches by rotating it (counter-clockwise quarter turns).
    nb_through = _line((a, -L), (a, L))
    nb_queue = _line((a, -L), (a, -H))
    theta = np.linspace(0.0, np.pi / 2, 73)
    arc = np.column_stack([-H + (H + a) * np.cos(theta), -H + (H + a) * np.sin(theta)])
    nb_left = np.vstack([[a, -L], arc, [-L, a]])
    through = {d: rot(nb_through, q) for q, d in enumerate("NWSE")}  # N=northbound, W=westbound...
    queue = {d: rot(nb_queue, q) for q, d in enumerate("NWSE")}
    left = {"N": nb_left, "S": rot(nb_left, 2)}

    def moving(paths, speed, share):
        return [_Stream(p, speed, share) for p in paths]

    return [
        (
            "north_south_through",
            0.3,
            moving([through["N"], through["S"]], 12.0, 0.3) + moving([queue["E"], queue["W"]], 0.0, 0.2),
        ),
        (
            "east_west_through",
            0.3,
            moving([through["E"], through["W"]], 12.0, 0.3) + moving([queue["N"], queue["S"]], 0.0, 0.2),
        ),
        ("left_turns", 0.2, moving([left["N"], left["S"]], 7.0, 0.3) + moving([queue["E"], queue["W"]], 0.0, 0.2)),
        ("stop_line_queue", 0.2, moving([queue[d] for d in "NWSE"], 0.0, 0.25)),
    ]


_KINDS = {"highway": _highway, "intersection": _intersection}


def _check_kind(kind: str) -> None:
    if kind not in _KINDS:
        raise InvalidInputError(f"kind must be one of {sorted(_KINDS)}, got {kind!r}")


def roi(kind: str) -> tuple[float, float, float, float]:
    """``(x_min, x_max, y_min, y_max)`` of the synthetic scene ``kind``, in metres."""
    _check_kind(kind)
    return _ROIS[kind]


def patterns(kind: str) -> list[tuple[str, float]]:
    """``(name, proportion)`` of each true pattern of ``kind``, in label order."""
    _check_kind(kind)
    return [(name, share) for name, share, _ in _KINDS[kind]()]


def _place(stream: _Stream, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``count`` vehicles uniformly along the stream's path: positions and noise-free velocities."""
    seg = np.diff(stream.path, axis=0)
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.r_[0.0, np.cumsum(seg_len)]
    s = rng.uniform(0.0, cum[-1], count)
    j = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    direction = seg[j] / seg_len[j, None]
    normal = np.column_stack([-direction[:, 1], direction[:, 0]])
    xy = stream.path[j] + direction * (s - cum[j])[:, None] + normal * rng.normal(0.0, 0.3, count)[:, None]
    return xy, stream.speed * direction


def _split(n: np.ndarray, shares: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Vehicles per stream for frames of ``n`` vehicles each, shape ``(len(n), len(shares))``:
    ``floor(n * share)`` each, the remainder drawn in proportion to the shares."""
    base = np.floor(n[:, None] * shares + 1e-9).astype(np.int64)
    extra = n - base.sum(axis=1)
    return base + rng.multinomial(extra, shares / shares.sum())


# Rows synthetic() will allocate at most (about 100 bytes each, all arrays together).
_MAX_ROWS = 50_000_000


def _as_int(name: str, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise InvalidInputError(f"{name} must be an integer, got {value!r}")
    return int(value)


def synthetic(
    kind: str = "highway",
    n_frames: int = 200,
    seed: int = 0,
    vehicles: tuple[int, int] = (8, 16),
    noise: float = 0.7,
) -> Frames:
    """Frames drawn from the known motion patterns of ``kind`` (see the module docstring).

    Exactly ``round(n_frames * proportion)`` frames per pattern (largest remainder), in random
    order; ``frames.labels`` holds each frame's pattern. The same arguments give the same frames.
    Positions may fall up to about a metre outside :func:`roi` (lateral jitter).
    """
    if not isinstance(kind, str):
        raise InvalidInputError(f"kind must be one of {sorted(_KINDS)}, got {kind!r}")
    _check_kind(kind)
    n_frames = _as_int("n_frames", n_frames)
    if n_frames < 1:
        raise InvalidInputError(f"n_frames must be at least 1, got {n_frames}")
    try:
        lo, hi = (_as_int("vehicles[0]", vehicles[0]), _as_int("vehicles[1]", vehicles[1]))
        if len(vehicles) != 2:
            raise TypeError
    except (TypeError, IndexError, KeyError):
        raise InvalidInputError(f"vehicles must be a pair of integers (min, max), got {vehicles!r}") from None
    if not 1 <= lo <= hi:
        raise InvalidInputError(f"vehicles must be (min, max) with 1 <= min <= max, got {vehicles!r}")
    if n_frames * hi > _MAX_ROWS:
        raise InvalidInputError(
            f"n_frames * vehicles[1] = {n_frames * hi} rows is too many (at most {_MAX_ROWS}); "
            "ask for fewer frames or vehicles"
        )
    try:
        noise = float(noise)
    except (TypeError, ValueError):
        raise InvalidInputError(f"noise must be a number, got {noise!r}") from None
    if not 0 <= noise < np.inf:
        raise InvalidInputError(f"noise must be a finite non-negative standard deviation, got {noise!r}")
    try:
        rng = np.random.default_rng(seed)
    except (TypeError, ValueError) as e:
        raise InvalidInputError(f"seed must be a non-negative integer, got {seed!r} ({e})") from None

    pats = _KINDS[kind]()
    props = np.array([share for _, share, _ in pats])
    raw = n_frames * props
    counts = np.floor(raw).astype(int)
    counts[np.argsort(-(raw - counts), kind="stable")[: n_frames - counts.sum()]] += 1
    labels = rng.permutation(np.repeat(np.arange(len(pats)), counts))
    sizes = rng.integers(lo, hi + 1, size=n_frames)

    # All frames of one pattern at once, then all vehicles of one stream at once: rows come
    # out grouped by stream and Frames.from_arrays regroups them by frame (stably, so a
    # frame's vehicles keep stream order).
    frame_col, xy_rows, v_rows = [], [], []
    for k, (_, _, streams) in enumerate(pats):
        members = np.flatnonzero(labels == k)
        if len(members) == 0:
            continue
        per_stream = _split(sizes[members], np.array([s.share for s in streams]), rng)
        for j, stream in enumerate(streams):
            c = per_stream[:, j]
            total = int(c.sum())
            if total:
                xy, v = _place(stream, total, rng)
                xy_rows.append(xy)
                v_rows.append(v)
                frame_col.append(np.repeat(members, c))
    xy, v = np.vstack(xy_rows), np.vstack(v_rows)
    v += rng.normal(0.0, noise, v.shape)
    return Frames.from_arrays(np.concatenate(frame_col), xy[:, 0], xy[:, 1], v[:, 0], v[:, 1], labels=labels)


__all__ = ["patterns", "roi", "synthetic"]
