"""Generated scenarios as ASAM OpenSCENARIO files, for the tools that replay them (esmini, CARLA
ScenarioRunner, commercial simulators).

One ``.xosc`` file per scenario, written with ``scenariogeneration`` (``pip install
dpgp[openscenario]``) in **OpenSCENARIO 1.2**: the newest version that the tools in use read
widely, and it has all this export needs — timed ``Polyline`` trajectories with absolute timing,
``DeleteEntityAction``, ``greaterOrEqual`` time rules, ``Properties`` in the file header. 1.3
adds nothing used here. Every file validates against the ``OpenSCENARIO_1_2.xsd`` that
scenariogeneration ships (:func:`validate`).

What a file holds, for scenario ``s`` of the table ``Scenarios.to_pandas()``:

- a ``ScenarioObject`` per generated vehicle (``vehicle{i}``, category ``car``; the scenario's
  ego vehicle, when :attr:`Scenarios.ego` names one, ``Ego``) or pedestrian
  (``pedestrian{i}``), with a bounding box centred on the tracked point: the size the model
  records (:mod:`dpgp.provenance`: the tracks' median length and width), else
  :data:`DEFAULT_SIZES`; per-row ``length``/``width``/``height`` columns in the table win;
- in ``Init``, a ``TeleportAction`` to its first position;
- a ``FollowTrajectoryAction`` (following mode ``position``, timing ``absolute``) along a
  ``Trajectory`` of one timed ``Polyline`` of ``WorldPosition`` vertices: every row of the table,
  ``x, y`` in metres, heading ``atan2(vy, vx)`` (unwrapped, so that headings interpolate without
  spinning; a standing object keeps its last heading);
- a vehicle whose rows end before the scenario's last time has left the ROI: its trajectory ends
  at its last position inside, and a ``DeleteEntityAction`` removes it once the simulation time
  is past that instant;
- traceability: the file header's description names the scenario, its pattern and the seed;
  ``ParameterDeclarations`` hold ``dpgp_scenario``, ``dpgp_pattern``, ``dpgp_seed``,
  ``dpgp_dt``, ``dpgp_units`` (the model's length unit), ``dpgp_origin_x``/``_y`` (model units)
  and ``dpgp_version``.

Coordinates: ``x_out = (x - origin_x) * scale`` with ``scale`` 0.3048 for feet and 1 for metres
(the model's recorded unit, or ``units=``). A model that records no unit is taken to be in
metres, with a warning. The road network is optional: none, or an OpenDRIVE file referenced by
path as given (``LogicFile``).
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import math
import os
import tempfile
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from ..exceptions import DataFormatError, InvalidInputError

if TYPE_CHECKING:
    import pandas as pd

#: OpenSCENARIO 1.<OSC_MINOR> is written and validated against.
OSC_MINOR = 2
#: (length, width, height) in metres when neither the table nor the model gives a size: a
#: mid-size car, and a walking adult (shoulder width 0.6 m, stride depth 0.5 m, 1.8 m tall).
DEFAULT_SIZES = {"vehicle": (4.5, 1.8, 1.5), "pedestrian": (0.5, 0.6, 1.8)}
#: Metres per length unit.
UNITS = {"m": 1.0, "ft": 0.3048}
#: A vehicle's dynamics limits, required by the schema and unused by a trajectory replay:
#: generous so that no tool clips the replayed motion (max speed m/s, acceleration m/s²).
_PERFORMANCE = (70.0, 10.0, 10.0)
_PEDESTRIAN_MASS = 75.0  # kg
_STANDING = 1e-9  # speeds below this (in the table's units per second) keep the last heading
_EXTRA_SIZE_COLUMNS = ("length", "width", "height")


def require_scenariogeneration() -> Any:
    """scenariogeneration's ``xosc`` module, or an ImportError that says what to install."""
    try:
        from scenariogeneration import xosc
    except ImportError:
        raise ImportError(
            "OpenSCENARIO export needs the scenariogeneration package: pip install 'dpgp[openscenario]' "
            "(or pip install scenariogeneration)"
        ) from None
    return xosc


def write_openscenario(
    scenarios: Any,
    path: str | os.PathLike,
    model: Any = None,
    *,
    units: str | float | None = None,
    origin: Sequence[float] = (0.0, 0.0),
    road_network: str | os.PathLike | None = None,
    object_type: str | None = None,
    size: Sequence[float] | None = None,
    seed: int | None = None,
    description: str | None = None,
    date: _dt.datetime | None = None,
    progress: bool = False,
) -> list[Path]:
    """Write ``scenarios`` (a :class:`dpgp.scenarios.Scenarios`) as OpenSCENARIO 1.2 files.

    Parameters
    ----------
    path
        A ``.xosc`` file (for a single scenario) or a directory, created if needed, that gets
        ``scenario_00000.xosc``, ``scenario_00001.xosc``, ... (one per scenario, by index).
    model
        The fitted model (or its :class:`~dpgp.fitted.FittedPatterns`) the scenarios came from:
        its recorded length unit, object type and object size are used. Optional.
    units
        The positions' unit, ``"m"``, ``"ft"`` or metres per unit; overrides the model's.
    origin
        ``(x, y)`` in the model's units, subtracted before conversion, to keep coordinates
        small (and to line them up with a road network). Recorded in every file.
    road_network
        Path of an OpenDRIVE file to reference (written as given); default none.
    object_type
        ``"vehicle"`` or ``"pedestrian"``; default the model's, else ``"vehicle"``.
    size
        ``(length, width)`` or ``(length, width, height)`` in metres; default the model's
        (converted), else :data:`DEFAULT_SIZES`.
    seed
        The seed the scenarios were generated with, recorded for traceability.
    description
        Text put before each file's own description (e.g. the model file's name).
    date
        The file header's date (default: now); fix it for byte-identical files.
    progress
        Show a progress bar.

    Returns the paths written. Each file is written to a temporary file and renamed, so an
    interrupted export leaves only whole files.
    """
    xosc = require_scenariogeneration()
    df = scenarios.to_pandas()
    n = len(scenarios)
    path = Path(path)
    single = path.suffix.lower() == ".xosc"
    if single and n != 1:
        raise InvalidInputError(
            f"{path} names one .xosc file but there are {n} scenarios; give a directory to get one file per scenario"
        )
    summary = _summary(model)
    scale, unit_name = _scale(units, summary)
    kind = _object_type(object_type, summary)
    box = _size(size, summary, scale, kind)
    ox, oy = _origin(origin)
    road = None if road_network is None else os.fspath(road_network)
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer))):
        raise InvalidInputError(f"seed must be a whole number or None, got {seed!r}")
    missing = [c for c in ("scenario", "vehicle", "t", "x", "y", "vx", "vy") if c not in df.columns]
    if missing:
        raise DataFormatError(f"the scenarios' table has no column(s) {missing}")

    for c in ("t", "x", "y", "vx", "vy"):
        if not np.all(np.isfinite(df[c].to_numpy(dtype=np.float64))):
            raise InvalidInputError(
                f"the scenarios' column {c!r} holds NaN or infinite values; OpenSCENARIO needs numbers"
            )

    from .._version import __version__

    order = np.lexsort((df["t"].to_numpy(), df["vehicle"].to_numpy(), df["scenario"].to_numpy()))
    cols = {c: df[c].to_numpy()[order] for c in df.columns}
    bounds = np.searchsorted(cols["scenario"].astype(np.int64), np.arange(n + 1))
    new_run = np.r_[
        True, (cols["scenario"][1:] != cols["scenario"][:-1]) | (cols["vehicle"][1:] != cols["vehicle"][:-1])
    ]
    cols["_heading"] = headings(cols["vx"], cols["vy"], np.flatnonzero(new_run[: len(order)]))  # all at once
    end = float(cols["t"].max()) if len(order) else 0.0  # every scenario runs as long as the longest
    seed_text = "none" if seed is None else str(int(seed))
    header = {
        "seed": seed_text,
        "dt": float(scenarios.dt) if n else float("nan"),
        "units": unit_name,
        "origin": (ox, oy),
        "version": str(__version__),
        "date": date or _dt.datetime.now().replace(microsecond=0),
        "end": end,
        "road": road,
    }
    patterns = np.asarray(scenarios.patterns)
    egos = getattr(scenarios, "ego", None)
    if single:
        targets = [path]
        path.parent.mkdir(parents=True, exist_ok=True)
    else:
        path.mkdir(parents=True, exist_ok=True)
        targets = [path / f"scenario_{s:05d}.xosc" for s in range(n)]
    template = _Template(xosc, header)
    bar = _bar(n, progress)
    try:
        for s in range(n):
            part = {c: v[bounds[s] : bounds[s + 1]] for c, v in cols.items()}
            objs = _objects(part, end, scale, (ox, oy), kind, box, -1 if egos is None else int(egos[s]))
            head = f"scenario {s} of {n}, pattern {int(patterns[s])}, seed {seed_text}"
            text = f"{description}: {head}" if description else f"dpgp generated {head}"
            _write_atomic(template.render(objs, s, int(patterns[s]), text), targets[s])
            if bar is not None:
                bar.update()
    finally:
        if bar is not None:
            bar.close()
    return targets


class _Object(NamedTuple):
    """One generated vehicle or pedestrian of a file, in the file's units (metres, seconds)."""

    name: str
    kind: str
    size: tuple[float, float, float]
    t: list[float]
    x: list[float]
    y: list[float]
    h: list[float]
    leaves: float | None  # when it is removed (its last time inside the ROI), else None


def _objects(
    part: dict[str, np.ndarray],
    end: float,
    scale: float,
    origin: tuple[float, float],
    kind: str,
    box: tuple[float, float, float],
    ego: int = -1,
) -> list[_Object]:
    """The objects of one scenario's rows (sorted by vehicle, then time); vehicle ``ego`` is
    named ``Ego`` (replay tools attach the vehicle under test to that name)."""
    veh = part["vehicle"].astype(np.int64)
    starts = np.flatnonzero(np.r_[True, veh[1:] != veh[:-1]]) if len(veh) else np.array([], dtype=np.int64)
    stops = np.r_[starts[1:], len(veh)]
    x = ((part["x"] - origin[0]) * scale).tolist()
    y = ((part["y"] - origin[1]) * scale).tolist()
    t = part["t"].astype(np.float64).tolist()
    out = []
    h = (part["_heading"] if "_heading" in part else headings(part["vx"], part["vy"], starts)).tolist()
    for a, b in zip(starts.tolist(), stops.tolist()):
        out.append(
            _Object("Ego" if int(veh[a]) == ego else f"{kind}{int(veh[a])}", kind, _row_size(part, a, box, scale), t[a:b], x[a:b], y[a:b], h[a:b],
                    t[b - 1] if t[b - 1] < end else None)
        )  # fmt: skip
    return out


def _scenario(xosc: Any, objs: list[_Object], header: dict[str, Any], s: Any, pattern: Any, text: str) -> Any:
    """One file's scenariogeneration object tree. Values may be OpenSCENARIO parameter
    references (``"$name"``): :class:`_Template` builds its text from such a tree."""
    xosc.VersionBase().setVersion(minor=OSC_MINOR)  # the library keeps the version globally
    params = xosc.ParameterDeclarations()
    for name, ptype, value in (
        ("dpgp_scenario", xosc.ParameterType.int, s),
        ("dpgp_pattern", xosc.ParameterType.int, pattern),
        ("dpgp_seed", xosc.ParameterType.string, header["seed"]),
        ("dpgp_dt", xosc.ParameterType.double, repr(header["dt"])),
        ("dpgp_units", xosc.ParameterType.string, header["units"]),
        ("dpgp_origin_x", xosc.ParameterType.double, repr(header["origin"][0])),
        ("dpgp_origin_y", xosc.ParameterType.double, repr(header["origin"][1])),
        ("dpgp_version", xosc.ParameterType.string, header["version"]),
    ):
        params.add_parameter(xosc.Parameter(name, ptype, str(value)))
    entities = xosc.Entities()
    init = xosc.Init()
    act = xosc.Act(f"scenario{s}", _time_trigger(xosc, "start", 0.0, xosc.Rule.greaterOrEqual))
    for o in objs:
        entities.add_scenario_object(o.name, _object(xosc, o.name, o.kind, o.size))
        init.add_init_action(o.name, xosc.TeleportAction(xosc.WorldPosition(o.x[0], o.y[0], 0.0, o.h[0])))
        maneuver = xosc.Maneuver(f"{o.name}_maneuver")
        if len(o.t) >= 2:  # a polyline needs two vertices; one row is just the teleport
            positions = [xosc.WorldPosition(px, py, 0.0, ph) for px, py, ph in zip(o.x, o.y, o.h)]
            trajectory = xosc.Trajectory(f"{o.name}_trajectory", False)
            trajectory.add_shape(xosc.Polyline(o.t, positions))
            follow = xosc.FollowTrajectoryAction(
                trajectory, xosc.FollowingMode.position, xosc.ReferenceContext.absolute, 1.0, 0.0
            )
            event = xosc.Event(f"{o.name}_follow", xosc.Priority.override)
            event.add_action(f"{o.name}_follow", follow)
            event.add_trigger(_time_trigger(xosc, f"{o.name}_start", 0.0, xosc.Rule.greaterOrEqual))
            maneuver.add_event(event)
        if o.leaves is not None:  # it left the ROI: removed once its trajectory has ended there
            event = xosc.Event(f"{o.name}_leaves", xosc.Priority.parallel)
            event.add_action(f"{o.name}_delete", xosc.DeleteEntityAction(o.name))
            event.add_trigger(_time_trigger(xosc, f"{o.name}_left_roi", o.leaves, xosc.Rule.greaterThan))
            maneuver.add_event(event)
        if maneuver.events:
            group = xosc.ManeuverGroup(f"{o.name}_group")
            group.add_actor(o.name)
            group.add_maneuver(maneuver)
            act.add_maneuver_group(group)
    storyboard = xosc.StoryBoard(init, _time_trigger(xosc, "end", header["end"], xosc.Rule.greaterThan, stop=True))
    if act.maneuvergroup:
        story = xosc.Story(f"scenario{s}_story", xosc.ParameterDeclarations())
        story.add_act(act)
        storyboard.add_story(story)
    return xosc.Scenario(
        text, f"dpgp {header['version']}", params, entities, storyboard, xosc.RoadNetwork(roadfile=header["road"]),
        xosc.Catalog(), osc_minor_version=OSC_MINOR, creation_date=header["date"],
    )  # fmt: skip


class _Template:
    """The text of a file, made once by scenariogeneration and filled in by string formatting.

    Building every file's object tree and serialising it took about five times as long as
    generating the scenarios; so :func:`_scenario` builds one file whose object carries
    placeholders (parameter references ``$vt``, ``$vx``..., names ``@N@``), and its text is cut
    into the pieces a file repeats per object and per vertex. A file with no story (no object
    moves or leaves) is written through the object tree itself. Tests check that both give the
    same bytes.
    """

    _NAME = "@N@"

    def __init__(self, xosc: Any, header: dict[str, Any]) -> None:
        self.xosc, self.header = xosc, header
        self._entities: dict[tuple[str, tuple[float, float, float]], str] = {}
        # The template of one object: placeholders ("$vt", ...) where its numbers go.
        placeholders: Any = (["$vt", "$vt"], ["$vx", "$vx"], ["$vy", "$vy"], ["$vh", "$vh"], "$leave")
        probe = _Object(self._NAME, "vehicle", (1.0, 1.0, 1.0), *placeholders)
        probe = probe._replace(x=["$ix", "$vx"], y=["$iy", "$vy"], h=["$ih", "$vh"])  # type: ignore[list-item]  # placeholders
        text = _serialize(_scenario(xosc, [probe], header, "@S@", "@P@", "@D@").get_element()).decode("utf-8")
        entity = _block(text, f'<ScenarioObject name="{self._NAME}"', "</ScenarioObject>")
        private = _block(text, f'<Private entityRef="{self._NAME}"', "</Private>")
        group = _block(text, "<ManeuverGroup ", "</ManeuverGroup>")
        follow = _block(group, "<Event ", "</Event>")
        leave = _block(group[group.index(follow) + len(follow) :], "<Event ", "</Event>")
        first = _block(follow, "<Vertex ", "</Vertex>")
        second = _block(follow[follow.index(first) + len(first) :], "<Vertex ", "</Vertex>")
        self.entity_pad = entity[1 : len(entity) - len(entity.lstrip(" \n"))]
        self.skeleton = text.replace(entity, "@ENTITIES@").replace(private, "@INIT@").replace(group, "@GROUPS@")
        # pieces split at the name, so that an object's name is put in by str.join
        self.private = _fmt(private, ("$ix", "$iy", "$ih")).split(self._NAME)
        group_head, rest = group.split(follow)
        follow_head, follow_tail = follow.split(first + second)
        self.group_head = group_head.split(self._NAME)
        self.follow_head, self.follow_tail = follow_head.split(self._NAME), follow_tail.split(self._NAME)
        self.leave = _fmt(leave, ("$leave",)).split(self._NAME)
        self.group_tail = rest.replace(leave, "").split(self._NAME)
        self._vertex = second
        self._vertices: dict[int, str] = {}

    def vertices(self, o: _Object) -> str:
        """The polyline's vertices of ``o``: one format string for all of them (one per count)."""
        k = len(o.t)
        if k not in self._vertices:
            self._vertices[k] = "".join(_fmt(self._vertex, ("$vt", "$vx", "$vy", "$vh"), 4 * i) for i in range(k))
        return self._vertices[k].format(*[v for row in zip(o.t, o.x, o.y, o.h) for v in row])

    def entity(self, o: _Object) -> str:
        key = (o.kind, o.size)
        if key not in self._entities:
            entities = self.xosc.Entities()
            entities.add_scenario_object(self._NAME, _object(self.xosc, self._NAME, o.kind, o.size))
            self._entities[key] = _serialize(entities.get_element()[0], self.entity_pad, declaration=False).decode(
                "utf-8"
            )
        return self._entities[key].replace(self._NAME, o.name)

    def render(self, objs: list[_Object], s: int, pattern: int, text: str) -> bytes:
        groups = []
        for o in objs:
            name = o.name
            parts = []
            if len(o.t) >= 2:
                parts += [name.join(self.follow_head), self.vertices(o), name.join(self.follow_tail)]
            if o.leaves is not None:
                parts.append(name.join(self.leave).format(o.leaves))
            if parts:
                groups += [name.join(self.group_head), *parts, name.join(self.group_tail)]
        if not groups:
            return _serialize(_scenario(self.xosc, objs, self.header, s, pattern, text).get_element())
        init = "".join(o.name.join(self.private).format(o.x[0], o.y[0], o.h[0]) for o in objs)
        head, rest = self.skeleton.split("@ENTITIES@")
        out = (
            head.replace("@S@", str(int(s))).replace("@P@", str(int(pattern))).replace("@D@", text.translate(_ESCAPES))
            + "".join(self.entity(o) for o in objs)
            + rest.replace("@INIT@", init).replace("@GROUPS@", "".join(groups)).replace("@S@", str(int(s)))
        )
        return out.encode("utf-8")


def _block(text: str, start: str, end: str) -> str:
    """The lines of ``text`` from the one holding the first ``start`` to the first ``end`` after it."""
    a = text.index(start)
    a = text.rindex("\n", 0, a)
    b = text.index(end, a) + len(end)
    return text[a:b]


def _fmt(piece: str, names: tuple[str, ...], first: int = 0) -> str:
    """``piece`` as a format string with the quoted placeholders ``names`` as fields ``first``,
    ``first + 1``, ..."""
    out = piece.replace("{", "{{").replace("}", "}}")
    for i, name in enumerate(names):
        out = out.replace(f'"{name}"', f'"{{{first + i}}}"')
    return out


def _time_trigger(xosc: Any, name: str, value: float, rule: Any, stop: bool = False) -> Any:
    condition = xosc.SimulationTimeCondition(value, rule)
    return xosc.ValueTrigger(name, 0.0, xosc.ConditionEdge.none, condition, "stop" if stop else "start")


def _object(xosc: Any, name: str, kind: str, size: tuple[float, float, float]) -> Any:
    length, width, height = size
    bb = xosc.BoundingBox(width, length, height, 0.0, 0.0, height / 2)
    if kind == "pedestrian":
        return xosc.Pedestrian(name, _PEDESTRIAN_MASS, xosc.PedestrianCategory.pedestrian, bb)
    wheel = min(0.6, height / 2)
    track = 0.85 * width
    front = xosc.Axle(0.5, wheel, track, 0.3 * length, wheel / 2)  # axles a wheelbase of 0.6 length apart
    rear = xosc.Axle(0.0, wheel, track, -0.3 * length, wheel / 2)
    return xosc.Vehicle(name, xosc.VehicleCategory.car, bb, front, rear, *_PERFORMANCE)


def headings(vx: np.ndarray, vy: np.ndarray, starts: np.ndarray | None = None) -> np.ndarray:
    """Heading (radians, counter-clockwise from +x) of each velocity, unwrapped along the rows
    (each step taken to (-π, π], as ``np.unwrap``); a row whose speed is (near) zero takes the
    last moving row's heading (before the first moving row: the first moving row's; none moving:
    0). ``starts``: the first rows of independent runs (vehicles), each treated on its own."""
    vx, vy = np.asarray(vx, dtype=np.float64), np.asarray(vy, dtype=np.float64)
    n = len(vx)
    starts = np.zeros(1 if n else 0, dtype=np.int64) if starts is None else np.asarray(starts, dtype=np.int64)
    if n == 0:
        return np.zeros(0)
    run = np.zeros(n, dtype=np.int64)
    run[starts[1:]] = 1
    run = np.cumsum(run)
    first, stop = starts[run], np.r_[starts[1:], n][run]
    moving = np.hypot(vx, vy) > _STANDING
    rows = np.arange(n)
    last = np.maximum.accumulate(np.where(moving, rows, -1))  # last moving row at or before
    following = np.minimum.accumulate(np.where(moving, rows, n)[::-1])[::-1]  # first at or after
    src = np.where(last >= first, last, np.where(following < stop, following, -1))
    h = np.where(src >= 0, np.arctan2(vy, vx)[np.maximum(src, 0)], 0.0)
    step = np.diff(h)
    wrapped = np.mod(step + np.pi, 2 * np.pi) - np.pi
    wrapped[(wrapped == -np.pi) & (step > 0)] = np.pi
    # whole turns added at each step, counted in integers so that a run's result does not
    # depend on the runs before it
    turns = np.r_[0, np.where(np.abs(step) < np.pi, 0, np.rint((wrapped - step) / (2 * np.pi))).astype(np.int64)]
    turns[starts] = 0  # no unwrapping across runs
    total = np.cumsum(turns)
    return h + 2 * np.pi * (total - total[first])


def _row_size(
    part: dict[str, np.ndarray], row: int, box: tuple[float, float, float], scale: float
) -> tuple[float, float, float]:
    """The object's size from the table's optional length/width/height columns (model units),
    falling back on ``box`` (metres) for each missing or unusable one."""
    out = list(box)
    for i, c in enumerate(_EXTRA_SIZE_COLUMNS):
        if c in part:
            v = float(part[c][row]) * scale
            if math.isfinite(v) and v > 0:
                out[i] = v
    return out[0], out[1], out[2]


def _summary(model: Any) -> Any:
    if model is None:
        return None
    from ..gp.fitted import as_fitted

    try:
        frames = as_fitted(model).frames
    except TypeError as e:
        raise InvalidInputError(f"model must be a fitted dpgp.DPGP or None: {e}") from None
    return getattr(frames, "summary", None)


def _scale(units: Any, summary: Any) -> tuple[float, str]:
    if units is None:
        recorded = getattr(summary, "length_unit", None)
        if recorded is None:
            warnings.warn(
                "the model does not record its positions' unit; writing them as metres (pass units='ft' or "
                "units='m' to say which)",
                stacklevel=3,
            )
            return 1.0, "m (assumed)"
        units = recorded
    if isinstance(units, str):
        if units.lower() not in UNITS:
            raise InvalidInputError(f"units must be 'm', 'ft' or metres per unit (a positive number), got {units!r}")
        return UNITS[units.lower()], units.lower()
    try:
        f = float(units)
    except (TypeError, ValueError):
        raise InvalidInputError(f"units must be 'm', 'ft' or metres per unit, got {units!r}") from None
    if isinstance(units, bool) or not math.isfinite(f) or f <= 0:
        raise InvalidInputError(f"units as a number is metres per unit and must be positive and finite, got {units!r}")
    return f, f"x{f:g} m"


def _object_type(object_type: str | None, summary: Any) -> str:
    kind = object_type or getattr(summary, "object_type", None) or "vehicle"
    if kind not in DEFAULT_SIZES:
        raise InvalidInputError(f"object_type must be 'vehicle' or 'pedestrian', got {kind!r}")
    return kind


def _size(size: Any, summary: Any, scale: float, kind: str) -> tuple[float, float, float]:
    default = DEFAULT_SIZES[kind]
    if size is None:
        recorded = getattr(summary, "object_size", None)
        if recorded is None:
            return default
        size = tuple(float(v) * scale for v in recorded)
    try:
        vals = [float(v) for v in size]
    except (TypeError, ValueError):
        raise InvalidInputError(
            f"size must be (length, width) or (length, width, height) in metres, got {size!r}"
        ) from None
    if len(vals) not in (2, 3) or not all(math.isfinite(v) and v > 0 for v in vals):
        raise InvalidInputError(
            f"size must be 2 or 3 positive lengths in metres (length, width[, height]), got {size!r}"
        )
    return vals[0], vals[1], vals[2] if len(vals) == 3 else default[2]


def _origin(origin: Any) -> tuple[float, float]:
    try:
        ox, oy = (float(v) for v in origin)
    except (TypeError, ValueError):
        raise InvalidInputError(f"origin must be (x, y) in the model's units, got {origin!r}") from None
    if not (math.isfinite(ox) and math.isfinite(oy)):
        raise InvalidInputError(f"origin must be finite, got {origin!r}")
    return ox, oy


def _write_atomic(data: bytes, target: Path) -> None:
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


_ESCAPES = str.maketrans(
    {"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "\n": "&#10;", "\r": "&#13;", "\t": "&#9;"}
)


def _serialize(element: ET.Element, pad: str = "", declaration: bool = True) -> bytes:
    """UTF-8 XML of an element tree of attributes only (as OpenSCENARIO is), indented by one
    space a level. ElementTree's own writer handles namespaces and text that this tree does not
    have, and took most of the export's time."""
    out = ['<?xml version="1.0" encoding="utf-8"?>'] if declaration else [""]

    def emit(el: ET.Element, pad: str) -> None:
        attrs = "".join(f' {k}="{str(v).translate(_ESCAPES)}"' for k, v in el.attrib.items())
        text = (el.text or "").strip().translate(_ESCAPES)
        if len(el):
            out.append(f"{pad}<{el.tag}{attrs}>{text}")
            for child in el:
                emit(child, pad + " ")
            out.append(f"{pad}</{el.tag}>")
        elif text:
            out.append(f"{pad}<{el.tag}{attrs}>{text}</{el.tag}>")
        else:
            out.append(f"{pad}<{el.tag}{attrs}/>")

    emit(element, pad)
    return ("\n".join(out) + ("\n" if declaration else "")).encode("utf-8")


def _bar(total: int, progress: bool) -> Any:
    if not progress:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc="OpenSCENARIO", unit="file")


# ---------------------------------------------------------------------------------------------
# Checking files: the schema, and reading trajectories back with scenariogeneration's reader
# ---------------------------------------------------------------------------------------------


def schema_path(minor: int = OSC_MINOR) -> Path:
    """The ``OpenSCENARIO_1_<minor>.xsd`` that scenariogeneration installs (beside its package)."""
    xosc = require_scenariogeneration()
    name = f"OpenSCENARIO_1_{minor}.xsd" if minor != 3 else "OpenSCENARIO_1_3_1.xsd"
    candidates = [Path(xosc.__file__).resolve().parents[2] / "schemas" / name]
    try:
        from importlib.metadata import files

        candidates += [Path(f.locate()) for f in files("scenariogeneration") or [] if f.name == name]
    except Exception:  # noqa: BLE001 - metadata is a fallback only
        pass
    for p in candidates:
        if p.is_file():
            return p
    raise FileNotFoundError(f"scenariogeneration's {name} was not found (looked in {[str(c) for c in candidates]})")


@lru_cache(maxsize=4)
def _schema(minor: int) -> Any:
    from lxml import etree

    return etree.XMLSchema(etree.parse(str(schema_path(minor))))


def validate(path: str | os.PathLike, minor: int = OSC_MINOR) -> list[str]:
    """The schema errors of the file at ``path`` against OpenSCENARIO 1.<minor>'s XSD (as
    scenariogeneration ships it), checked with lxml; an empty list when the file is valid."""
    from lxml import etree

    schema = _schema(minor)
    try:
        doc = etree.parse(os.fspath(path))
    except etree.XMLSyntaxError as e:
        return [f"not well-formed XML: {e}"]
    if schema.validate(doc):
        return []
    return [f"line {e.line}: {e.message}" for e in schema.error_log]


def read_openscenario(path: str | os.PathLike) -> pd.DataFrame:
    """Read the trajectories of a file this module wrote back with scenariogeneration's reader
    (``xosc.Scenario.parse``; ``xosc.ParseOpenScenario`` does the same after validating with
    xmlschema, which takes about a second a file).

    Returns one row per vertex: ``entity, vehicle, t, x, y, heading`` (metres, seconds,
    radians, as in the file; ``vehicle`` -1 for the ego vehicle, ``Ego``); an object with a single row (a teleport only) gives one row at
    ``t = 0``. ``attrs["parameters"]`` holds the ParameterDeclarations, ``attrs["description"]``
    the header's, ``attrs["deleted"]`` ``{entity: time}`` for the DeleteEntityActions,
    ``attrs["sizes"]`` ``{entity: (length, width, height)}`` and ``attrs["kinds"]``
    ``{entity: "vehicle" | "pedestrian"}``.
    """
    import pandas as pd

    xosc = require_scenariogeneration()
    scenario = xosc.Scenario.parse(ET.parse(os.fspath(path)).getroot())
    rows: dict[str, list[Any]] = {c: [] for c in ("entity", "t", "x", "y", "heading")}
    followed: set[str] = set()
    deleted: dict[str, float] = {}
    for story in scenario.storyboard.stories:
        for act in story.acts:
            for group in act.maneuvergroup:
                (ref,) = group.actors.actors
                actor = ref.entity
                for maneuver in group.maneuvers:
                    for event in maneuver.events:
                        for item in event.action:
                            action = item.action
                            if isinstance(action, xosc.FollowTrajectoryAction):
                                poly = action.trajectory.shapes
                                followed.add(actor)
                                rows["entity"] += [actor] * len(poly.positions)
                                rows["t"] += list(poly.time)
                                rows["x"] += [p.x for p in poly.positions]
                                rows["y"] += [p.y for p in poly.positions]
                                rows["heading"] += [p.h for p in poly.positions]
                            elif isinstance(action, xosc.DeleteEntityAction):
                                cond = event.trigger.conditiongroups[0].conditions[0].valuecondition
                                deleted[action.entityref] = float(cond.value)
    for name, actions in scenario.storyboard.init.initactions.items():
        if name not in followed:  # a teleport only
            pos = actions[0].position
            rows["entity"].append(name)
            rows["t"].append(0.0)
            rows["x"].append(pos.x)
            rows["y"].append(pos.y)
            rows["heading"].append(pos.h)
    df = pd.DataFrame(rows)
    # the ego vehicle (named Ego) has no number: -1
    df.insert(1, "vehicle", pd.to_numeric(df["entity"].str.extract(r"(\d+)$")[0]).fillna(-1).astype(np.int64))
    df = df.sort_values(["vehicle", "t"], kind="stable", ignore_index=True)
    kinds: dict[str, str] = {}
    sizes: dict[str, tuple[float, float, float]] = {}
    for obj in scenario.entities.scenario_objects:
        entity = obj.entityobject
        kinds[obj.name] = "pedestrian" if isinstance(entity, xosc.Pedestrian) else "vehicle"
        dim = entity.boundingbox.boundingbox
        sizes[obj.name] = (dim.length, dim.width, dim.height)
    df.attrs["parameters"] = {p.name: p.value for p in scenario.parameters.parameters}
    df.attrs["description"] = scenario.header.description
    df.attrs["deleted"] = deleted
    df.attrs["sizes"] = sizes
    df.attrs["kinds"] = kinds
    return df


__all__ = [
    "write_openscenario",
    "require_scenariogeneration",
    "read_openscenario",
    "validate",
    "schema_path",
    "headings",
    "DEFAULT_SIZES",
    "OSC_MINOR",
    "UNITS",
]
