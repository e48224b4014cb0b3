"""Fuzz cases over dpgp's public surfaces (issue 11), shared by ``tests/test_fuzz.py`` (hypothesis,
a fixed slice in CI) and ``benches/fuzz.py`` (the standalone runner of the full 10,000-case run).

A case is a function of a :class:`Draw`, which hands out choices: :class:`RandomDraw` makes them
from a seeded numpy generator (the runner: case ``surface:i`` is always the same case), and
:class:`HypothesisDraw` from hypothesis' ``data()`` strategy (the tests: shrinking, replay). Every
case runs one call on a public surface with hostile arguments or damaged files and is classified:

``valid``      it returned, and nothing it returned holds NaN or +inf;
``typed``      it raised a dpgp exception (or FileNotFoundError & co. for a missing path) with a
               message;
defects        ``untyped`` (any other exception), ``nonfinite`` (NaN/inf in a result),
               ``cli`` (the CLI raised, printed a traceback or more than one line of error, or
               failed silently), ``tempfile`` (a temporary file left behind); the runner adds
               ``crash`` (the process died: panic, abort) and ``hang`` (over the time limit).
"""

from __future__ import annotations

import contextlib
import gzip
import io
import json
import math
import os
import shutil
import struct
import tempfile
import traceback
import zipfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import dpgp

SURFACES = ("readers", "arrays", "framing", "fit", "model_files", "model_use", "cli")
DEFECTS = ("untyped", "nonfinite", "cli", "tempfile", "crash", "hang")
DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"

# OS errors that name a path the user gave: typed enough (the message says which file).
_PATH_ERRORS = (FileNotFoundError, IsADirectoryError, NotADirectoryError, PermissionError, FileExistsError)

# Arguments that are known to kill or stall the interpreter (open defects outside the fuzz's
# own files): in-process runs (CI) leave them out; the runner isolates every case and keeps them.
UNSAFE_IN_PROCESS = "unsafe"


# ---------------------------------------------------------------------------------------------
# where the choices come from
# ---------------------------------------------------------------------------------------------
class Draw:
    """Choices for one case; ``log`` records them (the reproducer of a case)."""

    safe = False  # in-process: leave out the arguments known to crash the interpreter

    def __init__(self) -> None:
        self.log: list[str] = []

    verbose = False  # print each choice as it is made (replaying a case that hangs)

    def _note(self, label: str, value: Any) -> Any:
        text = repr(value)
        self.log.append(f"{label}={text if len(text) <= 120 else text[:117] + '...'}")
        if self.verbose:
            print("  draw:", self.log[-1], flush=True)
        return value

    def integer(self, lo: int, hi: int, label: str = "int") -> int:
        raise NotImplementedError

    def uniform(self, lo: float, hi: float, label: str = "float") -> float:
        raise NotImplementedError

    def index(self, n: int) -> int:
        raise NotImplementedError

    def choice(self, options: Sequence[Any], label: str = "choice") -> Any:
        options = [o for o in options if not (self.safe and isinstance(o, Unsafe))]
        value = options[self.index(len(options))]
        value = value.value if isinstance(value, Unsafe) else value
        return self._note(label, value)

    def boolean(self, label: str = "bool", p: float = 0.5) -> bool:
        return self._note(label, self.uniform(0.0, 1.0, "_") < p) if p not in (0.0, 1.0) else p == 1.0

    def maybe(self, valid: Sequence[Any], hostile: Sequence[Any], label: str, p_hostile: float = 0.35) -> Any:
        """A valid value mostly, a hostile one with probability ``p_hostile``."""
        hostile_now = self.uniform(0.0, 1.0, "_") < p_hostile
        return self.choice(hostile if hostile_now else valid, label)


class RandomDraw(Draw):
    def __init__(self, seed: Sequence[int] | int, safe: bool = False) -> None:
        super().__init__()
        self.rng = np.random.default_rng(seed)
        self.safe = safe

    def integer(self, lo: int, hi: int, label: str = "int") -> int:
        return self._note(label, int(self.rng.integers(lo, hi + 1)))

    def uniform(self, lo: float, hi: float, label: str = "float") -> float:
        value = float(self.rng.uniform(lo, hi))
        return value if label == "_" else self._note(label, value)

    def index(self, n: int) -> int:
        return int(self.rng.integers(0, n))


class HypothesisDraw(Draw):
    def __init__(self, data: Any, safe: bool = True) -> None:
        super().__init__()
        self.data = data
        self.safe = safe

    def integer(self, lo: int, hi: int, label: str = "int") -> int:
        from hypothesis import strategies as st

        return self._note(label, self.data.draw(st.integers(lo, hi)))

    def uniform(self, lo: float, hi: float, label: str = "float") -> float:
        from hypothesis import strategies as st

        value = self.data.draw(st.floats(lo, hi, exclude_max=hi > lo))
        return value if label == "_" else self._note(label, value)

    def index(self, n: int) -> int:
        from hypothesis import strategies as st

        return self.data.draw(st.integers(0, n - 1))


@dataclass(frozen=True)
class Unsafe:
    """A hostile value that is known to crash the interpreter (left out in-process)."""

    value: Any


# ---------------------------------------------------------------------------------------------
# outcomes
# ---------------------------------------------------------------------------------------------
@dataclass
class Outcome:
    kind: str  # valid, typed, or one of DEFECTS
    detail: str = ""

    @property
    def defect(self) -> bool:
        return self.kind in DEFECTS


def where(e: BaseException) -> str:
    """``file:line in function`` of the deepest dpgp frame of a traceback (the defect's place)."""
    frames = traceback.extract_tb(e.__traceback__)
    own = [f for f in frames if "/dpgp/" in f.filename.replace(os.sep, "/")]
    f = (own or frames or [None])[-1]
    if f is None:
        return "?"
    return f"{Path(f.filename).parent.name}/{Path(f.filename).name}:{f.lineno} in {f.name}"


def classify_exception(e: BaseException) -> Outcome:
    msg = " ".join(str(e).split())
    if isinstance(e, dpgp.DpgpError) or type(e) in _PATH_ERRORS:
        return (
            Outcome("typed", f"{type(e).__name__}: {msg[:160]}")
            if msg
            else Outcome("untyped", f"{type(e).__name__} without a message at {where(e)}")
        )
    return Outcome("untyped", f"{type(e).__name__} at {where(e)}: {msg[:160]}")


def nonfinite(value: Any, allow_neg_inf: bool = False, depth: int = 0) -> str | None:
    """Where ``value`` holds NaN or inf, else None; ``-inf`` is allowed only where a case says so
    (the paper's unsmoothed φ, ψ, asked for explicitly), and a masked array's masked entries
    are no values at all."""
    if depth > 4:
        return None
    if isinstance(value, np.ma.MaskedArray):  # masked entries are documented "no value" (issue 36)
        value = np.ma.getdata(value)[~np.ma.getmaskarray(value)]
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "fc":
            bad = np.isnan(value) | (np.isposinf(value) if allow_neg_inf else np.isinf(value))
            if value.dtype.kind == "c":
                bad = ~np.isfinite(value)
            if bad.any():
                return f"array of shape {value.shape} with {int(bad.sum())} non-finite value(s)"
        return None
    if isinstance(value, (float, np.floating)):
        v = float(value)
        if math.isnan(v) or (math.isinf(v) and not (allow_neg_inf and v < 0)):
            return f"the number {v}"
        return None
    if isinstance(value, (list, tuple)):
        for i, item in enumerate(value[:50]):
            got = nonfinite(item, allow_neg_inf, depth + 1)
            if got:
                return f"[{i}]: {got}"
        return None
    if isinstance(value, dict):
        for k, item in list(value.items())[:50]:
            got = nonfinite(item, allow_neg_inf, depth + 1)
            if got:
                return f"[{k!r}]: {got}"
        return None
    if isinstance(value, dpgp.Frames):
        return nonfinite((value.xy, value.v), False, depth + 1)
    if isinstance(value, dpgp.DPGP):
        parts = {name: getattr(value, name, None) for name in ("weights_", "alpha_", "length_scales_", "log_joint_")}
        parts["history"] = {
            k: np.asarray(v, dtype=float) for k, v in getattr(value, "history_", {}).items() if k != "ari"
        }
        return nonfinite(parts, False, depth + 1)
    if isinstance(value, dpgp.Simulation):
        return nonfinite((value.positions, value.velocities, value.t), False, depth + 1)
    if isinstance(value, dpgp.Scenarios):
        return nonfinite(list(value.simulations), False, depth + 1)
    if hasattr(value, "columns") and hasattr(value, "to_numpy"):  # a table: its canonical columns
        cols = [c for c in ("t", "x", "y", "vx", "vy") if c in value.columns]
        return nonfinite({c: value[c].to_numpy(dtype=float) for c in cols}, False, depth + 1)
    return None


# ---------------------------------------------------------------------------------------------
# shared resources of a run: data copies, a tiny fitted model, a scratch directory
# ---------------------------------------------------------------------------------------------
_DATA_FILES = {
    # name -> (file in shared/data, lines kept; the readers must stay fast)
    "frames_csv": ("ngsim_lankershim_frames.csv", 120),
    "frames_tsv": ("ngsim_us101_frames.tsv", 120),
    "sumo_frames": ("sumo_left_turn_frames.csv", 120),
    "ngsim_raw": ("ngsim_peachtree_raw.csv", 160),
    "eth_ucy": ("eth_ucy_biwi_eth.txt", 160),
    "eth_ucy_zara": ("eth_ucy_crowds_zara01.txt", 160),
}


class Context:
    """Everything cases share; build one per process (``close()`` removes its directory)."""

    def __init__(self) -> None:
        self.root = Path(tempfile.mkdtemp(prefix="dpgp-fuzz-"))
        self._data: dict[str, bytes] | None = None
        self._model: Any = None
        self._checkpoint: bytes | None = None
        self._counter = 0

    def close(self) -> None:
        shutil.rmtree(self.root, ignore_errors=True)

    @property
    def data(self) -> dict[str, bytes]:
        """Heads of the real data files (copied, never the originals) and a SUMO FCD XML."""
        if self._data is None:
            if not DATA.exists():
                raise FileNotFoundError(f"the real data in {DATA} is absent")
            data = {}
            for name, (file, lines) in _DATA_FILES.items():
                with open(DATA / file, "rb") as fh:
                    data[name] = b"".join(fh.readline() for _ in range(lines))
            data["sumo_xml"] = _fcd_xml(data["sumo_frames"])
            self._data = data
        return self._data

    @property
    def model(self) -> Any:
        """A tiny fitted model (12 synthetic frames, one sweep) and its model-file bytes."""
        if self._model is None:
            frames = dpgp.datasets.synthetic("intersection", n_frames=12, seed=0, vehicles=(2, 5))
            model = dpgp.DPGP(iterations=1, seed=0, progress=False).fit(frames)
            path = self.root / "base.npz"
            model.save(path)
            self._model = (model, path.read_bytes())
        return self._model

    @property
    def checkpoint(self) -> bytes:
        """The bytes of a tiny fit's checkpoint (3 sweeps, every 2: the model is past its resume point)."""
        if self._checkpoint is None:
            frames = dpgp.datasets.synthetic("intersection", n_frames=12, seed=0, vehicles=(2, 5))
            path = self.root / "base.ckpt"
            dpgp.DPGP(iterations=3, seed=0, progress=False, checkpoint=str(path), checkpoint_every=2).fit(frames)
            self._checkpoint = path.read_bytes()
        return self._checkpoint

    def case_dir(self) -> Path:
        self._counter += 1
        d = self.root / f"case{self._counter}"
        d.mkdir()
        return d


def _fcd_xml(frames_csv: bytes) -> bytes:
    """SUMO FCD XML from the SUMO frames table (vehicle ids by their row inside a frame)."""
    rows = [line.split(",") for line in frames_csv.decode().splitlines()[1:] if line.strip()]
    out = ['<?xml version="1.0" encoding="UTF-8"?>', "<fcd-export>"]
    last, k = None, 0
    for frame, x, y, vx, vy in rows:
        if frame != last:
            if last is not None:
                out.append("  </timestep>")
            out.append(f'  <timestep time="{float(frame) * 0.5:.2f}">')
            last, k = frame, 0
        speed = math.hypot(float(vx), float(vy))
        angle = math.degrees(math.atan2(float(vx), float(vy))) % 360
        out.append(f'    <vehicle id="v{k}" x="{x}" y="{y}" angle="{angle:.3f}" speed="{speed:.3f}"/>')
        k += 1
    out += ["  </timestep>", "</fcd-export>", ""]
    return "\n".join(out).encode()


# ---------------------------------------------------------------------------------------------
# hostile values
# ---------------------------------------------------------------------------------------------
NAN, INF = float("nan"), float("inf")
HOSTILE_SCALARS = [
    0,
    -1,
    0.5,
    -0.0,
    1e-300,
    1e300,
    1e308,
    -1e308,
    NAN,
    INF,
    -INF,
    2**31,
    2**63,
    2**64,
    -(2**63),
    10**30,
    True,
    None,
    "1",
    "x",
    "",
    b"1",
    [1],
    (1, 2),
    {},
    1 + 2j,
    np.float32(2.5),
    np.int64(-5),
    np.array([1.0, 2.0]),
    np.nan,
    np.uint64(2**64 - 1),
    object(),
]
#: Extreme but finite magnitudes (issue 17): each must work with finite results or be refused
#: up front with a typed error naming the limit.
EXTREME = [1e154, -1e154, 1e200, 1e300, 1.7e308, -1.7e308, 5e-324, 1e-200, 1e-154, 2.2250738585072014e-308]
HOSTILE_TEXT = [
    "nan",
    "inf",
    "-inf",
    "",
    " ",
    "1e309",
    "-0",
    "abc",
    "1,000",
    '"',
    "\x00",
    "NULL",
    "１２",
    "0x1F",
    "--1",
    "1e-400",
    "None",
]


def scale_values(draw: Draw, n: int, label: str) -> np.ndarray:
    """``n`` coordinates of a hostile magnitude: big offsets, mm/km scale, duplicates, 1e154..."""
    kind = draw.choice(["plain", "plain", "plain", "offset", "tiny", "huge", "dup", "extreme", "int"], label + ".kind")
    base = np.array([draw.uniform(-50.0, 50.0, label) for _ in range(min(n, 3))] or [0.0])
    vals = np.resize(base, n) + np.arange(n) * 0.37
    if kind == "offset":
        vals = vals + 6.0e6
    elif kind == "tiny":
        vals = vals * 1e-3
    elif kind == "huge":
        vals = vals * 1e3
    elif kind == "dup":
        vals = np.full(n, vals[0])
    elif kind == "extreme":
        vals = vals * draw.choice([1e154, 1e200, 1e-200, 1e300, 1e-320], label + ".factor")
    elif kind == "int":
        vals = np.round(vals).astype(np.int64)
    if draw.boolean(label + ".bad", 0.04):  # one value that is not a finite number
        vals = vals.astype(object)
        vals[draw.index(n)] = draw.choice([NAN, INF, "3", None, -INF], label + ".bad_value")
    return vals


def tiny_frames_arrays(draw: Draw) -> tuple[np.ndarray, ...]:
    """1-3 frames of 1-5 vehicles with hostile coordinates and velocities."""
    sizes = [draw.integer(1, 5, "vehicles") for _ in range(draw.integer(1, 3, "frames"))]
    frame = np.repeat(np.arange(len(sizes)), sizes)
    n = len(frame)
    return (
        frame,
        scale_values(draw, n, "x"),
        scale_values(draw, n, "y"),
        scale_values(draw, n, "vx"),
        scale_values(draw, n, "vy"),
    )


# ---------------------------------------------------------------------------------------------
# file corruption
# ---------------------------------------------------------------------------------------------
def corrupt_text(draw: Draw, data: bytes) -> bytes:
    """One to three edits of a text table: truncation, bit flips, bad fields, lost header..."""
    for _ in range(draw.integer(1, 3, "edits")):
        op = draw.choice(
            [
                "truncate",
                "flip",
                "drop_line",
                "dup_line",
                "field",
                "garbage_line",
                "delimiter",
                "no_header",
                "header_field",
                "empty",
                "only_header",
                "bom",
                "latin1",
                "nul",
                "crlf",
                "blank_lines",
                "long_line",
            ],
            "op",
        )
        lines = data.split(b"\n")
        if op == "truncate" and data:
            data = data[: draw.integer(0, len(data) - 1, "at")]
        elif op == "flip" and data:
            buf = bytearray(data)
            for _ in range(draw.integer(1, 8, "bits")):
                buf[draw.index(len(buf))] ^= 1 << draw.integer(0, 7, "bit")
            data = bytes(buf)
        elif op == "drop_line" and len(lines) > 1:
            del lines[draw.index(len(lines))]
            data = b"\n".join(lines)
        elif op == "dup_line" and lines:
            i = draw.index(len(lines))
            lines.insert(i, lines[i])
            data = b"\n".join(lines)
        elif op in ("field", "header_field") and lines:
            i = 0 if op == "header_field" else draw.index(len(lines))
            sep = b"\t" if b"\t" in lines[i] else (b"," if b"," in lines[i] else b" ")
            fields = lines[i].split(sep)
            fields[draw.index(len(fields))] = draw.choice(HOSTILE_TEXT + ["x", "frame", "vx"], "text").encode("utf-8")
            lines[i] = sep.join(fields)
            data = b"\n".join(lines)
        elif op == "garbage_line":
            lines.insert(
                draw.index(len(lines) + 1),
                draw.choice([b"#", b"a,b", b"1", b";;;;", b"\t\t\t", b"\xff\xfe", b"1 2 3 4 5 6 7 8 9"], "line"),
            )
            data = b"\n".join(lines)
        elif op == "delimiter" and lines:
            i = draw.index(len(lines))
            lines[i] = lines[i].replace(b",", b";").replace(b"\t", b",")
            data = b"\n".join(lines)
        elif op == "no_header":
            data = b"\n".join(lines[1:])
        elif op == "empty":
            data = draw.choice([b"", b"\n", b" \n\n", b"\xef\xbb\xbf"], "content")
        elif op == "only_header":
            data = lines[0] + b"\n"
        elif op == "bom":
            data = b"\xef\xbb\xbf" + data
        elif op == "latin1":
            data = data.replace(b"x", b"\xe9", 1)
        elif op == "nul" and data:
            i = draw.index(len(data))
            data = data[:i] + b"\x00" + data[i:]
        elif op == "crlf":
            data = data.replace(b"\n", b"\r\n")
        elif op == "blank_lines":
            data = data.replace(b"\n", b"\n\n", 3)
        elif op == "long_line":
            data = data + b"\n" + b"1," * 5000
    return data


def write_corrupted(draw: Draw, ctx: Context, d: Path, name: str) -> Path:
    """A damaged copy of real data file ``name`` in ``d``: corrupted text, maybe gzip (itself
    maybe truncated), under a name whose extension may lie."""
    data = ctx.data[name]
    if draw.boolean("corrupt", 0.85):
        data = corrupt_text(draw, data)
    ext = {"sumo_xml": ".xml", "frames_tsv": ".tsv", "eth_ucy": ".txt", "eth_ucy_zara": ".txt"}.get(name, ".csv")
    ext = draw.choice([ext, ext, ext, ".parquet", ".xml", ".txt"], "ext")
    if draw.boolean("gzip", 0.2):
        data = gzip.compress(data)
        if draw.boolean("truncate_gz", 0.6) and len(data) > 1:
            data = data[: draw.integer(1, len(data) - 1, "gz_at")]
        ext += ".gz"
    path = d / ("data" + ext)
    path.write_bytes(data)
    return path


# ---------------------------------------------------------------------------------------------
# the surfaces: each returns (value, allow_neg_inf) or raises; the CLI returns an Outcome
# ---------------------------------------------------------------------------------------------
def case_readers(draw: Draw, ctx: Context, d: Path) -> Any:
    name = draw.choice(sorted(ctx.data), "file")
    path = as_drawn_path(draw, write_corrupted(draw, ctx, d, name))
    reader = draw.choice(["read_frames", "read_tracks", "read_ngsim", "tracks+frames", "preset"], "reader")
    if reader == "read_frames":
        return dpgp.read_frames(path)
    if reader == "read_ngsim":
        return dpgp.read_ngsim(path, split_gap=draw.maybe([1.0, 0.5], [0, -1, NAN, "x", None], "split_gap"))
    if reader == "preset":
        preset = draw.choice(
            ["eth_ucy", "interaction", "highd", "ind", "sumo", "ngsim", "fcd", "bogus", None], "preset"
        )
        return dpgp.read_tracks(path, preset=preset, sort=draw.boolean("sort"))
    kwargs: dict[str, Any] = {}
    if name in ("frames_csv", "frames_tsv", "sumo_frames"):
        kwargs = dict(
            id=draw.choice(["x", "frame", "frame_idx", 0, "nope"], "id"), t=draw.choice(["frame", "frame_idx", 1], "t")
        )
    elif name.startswith("eth"):
        kwargs = dict(preset="eth_ucy")
    tracks = dpgp.read_tracks(path, sort=draw.boolean("sort"), **kwargs)
    if reader == "read_tracks":
        return tracks
    return dpgp.make_frames(tracks, dt=draw.maybe([0.5, 0.4, 1.0], [1e-9, 1e300, 0.0], "dt"))


def _astype(c: np.ndarray, dtype: Any) -> np.ndarray:
    """``c`` converted, or ``c`` itself where it does not convert (an earlier damage made it text)."""
    try:
        return c.astype(dtype)
    except (TypeError, ValueError):
        return c


def case_arrays(draw: Draw, ctx: Context, d: Path) -> Any:
    target = draw.choice(
        ["from_arrays", "from_arrays", "select", "synthetic", "distributions", "ari", "read_frames_df", "gp", "gp",
         "frames"],
        "target",
    )  # fmt: skip
    if target == "gp":
        return gp_case(draw)
    if target == "frames":
        return frames_constructor_case(draw, ctx)
    if target in ("from_arrays", "select"):
        frame, x, y, vx, vy = tiny_frames_arrays(draw)
        cols = [frame, x, y, vx, vy]
        for _ in range(draw.integer(0, 2, "damages")):
            i = draw.index(5)
            c = cols[i] if isinstance(cols[i], np.ndarray) and cols[i].ndim == 1 else np.zeros(len(frame))
            cols[i] = draw.choice(
                [
                    c[:-1],
                    np.r_[c, c[:1]],
                    c.reshape(-1, 1),
                    c.astype(str),
                    [],
                    None,
                    "abc",
                    3.0,
                    np.array([]),
                    _astype(c, complex),
                    _astype(c, np.float32),
                    np.full(len(c), NAN),
                    np.array([[1, 2], [3, 4]]),
                    _astype(c, bool),
                    list(c),
                    np.array(["2020-01-01"] * len(c), dtype="datetime64[ns]"),
                    np.full(len(c), None),
                ],
                f"col{i}",
            )
        labels = draw.choice([None, None, [0], np.arange(3), "x", [None], np.array([1.5, NAN, 2.0])], "labels")
        frames = dpgp.Frames.from_arrays(*cols, labels=labels)
        if target == "from_arrays":
            return frames
        sel = draw.choice(
            [
                slice(0, 0),
                slice(None, None, -1),
                np.array([True]),
                np.array([0, 0]),
                [],
                np.array([5]),
                np.array([-1]),
                np.array([0.5]),
                "a",
                None,
                np.array([True, False, True, False, True]),
                [[0]],
                np.array([2**63 - 1]),
            ],
            "selection",
        )
        return frames[sel]
    if target == "synthetic":
        return dpgp.datasets.synthetic(
            draw.maybe(["highway", "intersection"], [None, 3, "", "HIGHWAY"], "kind"),
            draw.maybe([1, 2, 7], [0, -1, 2.5, "3", None, 10**12, True], "n_frames"),
            draw.maybe([0, 1], [-1, "s", 2**200, 1.5, None], "seed"),
            draw.maybe([(1, 3), (2, 2)], [(0, 1), (3, 1), (1,), None, ("a", 2), (1, 10**10), (1.5, 2)], "vehicles"),
            draw.maybe([0.0, 0.7], [-1, NAN, INF, "x", None, 1e308], "noise"),
        )
    if target == "distributions":
        frame, x, y, vx, vy = tiny_frames_arrays(draw)
        frames = dpgp.Frames.from_arrays(frame, x, y, vx, vy)
        dist = dpgp.EmpiricalDistributions.from_frames(
            frames,
            roi=draw.maybe(
                [None], [(0, 1, 0, 1), (1, 0, 0, 1), (NAN, 1, 0, 1), (0, 1e308, -1e308, 1e308), "abcd", (0, 1)], "roi"
            ),
            bins=draw.maybe([(3, 4), 5], [0, -1, (1, 2, 3), 2.5, "3", 10**12, (10**6, 10**6)], "bins"),
            pseudocount=draw.maybe(
                ["auto", 0.0, 1.0, (0.5, 2.0)], [-1, NAN, INF, "x", (1, 2, 3), (0.5, NAN)], "pseudocount"
            ),
        )
        paper = dist.is_paper_form  # pseudo-counts 0, asked for: -inf is its documented answer
        op = draw.choice(["count", "pos", "frame", "held_out", "sample_counts", "sample_positions"], "op")
        if op == "count":
            return dist.log_count_pmf(draw.choice([0, 1, 3, -1, 2.5, 10**30, NAN, "x", [1, 2], None], "l")), paper
        if op == "pos":
            return dist.log_position_density(
                draw.choice([[[0, 0]], [[NAN, 0]], [0, 0], "x", [[1e308, 1e308]], [], [[6e6, -6e6]]], "xy")
            ), paper
        xy = draw.choice([[[0, 0]], [[1, 2], [3, 4]], [], "x", [[1e99, 0]] * 40], "xy")
        if op == "frame":
            return dist.log_frame_density(xy), paper
        if op == "held_out":  # smoothed whatever the pseudo-counts: finite
            return dist.held_out_log_density(xy)
        n = draw.maybe([0, 3], [-1, 2.5, 10**15, None, "3"], "n")
        seed = draw.choice([0, None, -1, "x"], "rng")
        return dist.sample_counts(n, seed) if op == "sample_counts" else dist.sample_positions(n, seed)
    if target == "ari":
        a = draw.choice([[0, 1, 1], [0], [], [[0, 1]], "abc", [NAN, 1.0, NAN], [None, 1, 2], [0, 1]], "a")
        b = draw.choice([[1, 0, 0], [0], [], [0, 1], [None, "a", 2], [NAN, NAN, 1.0]], "b")
        return dpgp.adjusted_rand_index(a, b)
    import pandas as pd

    frame, x, y, vx, vy = tiny_frames_arrays(draw)
    df = pd.DataFrame({"frame": frame, "x": x, "y": y, "vx": vx, "vy": vy})
    if draw.boolean("rename"):
        df = df.rename(
            columns={draw.choice(list(df.columns), "col"): draw.choice(["X", "", 0, "frame", "vel_x"], "name")}
        )
    return dpgp.read_frames(df, **draw.choice([{}, {"x": "nope"}, {"frame": "x"}, {"vx": 3}], "names"))


def gp_case(draw: Draw) -> Any:
    """dpgp.gp's functions on extreme magnitudes of positions, velocities and parameters (issue
    17): a finite log density or a typed refusal, never -inf or NaN."""
    from dpgp import gp

    n = draw.integer(1, 5, "n")
    xy = np.column_stack([scale_values(draw, n, "x"), scale_values(draw, n, "y")])
    v = np.column_stack([scale_values(draw, n, "vx"), scale_values(draw, n, "vy")])
    pick = lambda valid, label: draw.maybe(valid, [*EXTREME, 0.0, -1.0, NAN], label)  # noqa: E731
    params = gp.GPParams((pick([5.0], "wx"), pick([3.0], "wy")), pick([1.0, 2.0], "signal_var"),
                         pick([0.5, 1.0], "noise_var"), pick([0.0, 1.0], "mean"))  # fmt: skip
    fn = draw.choice(["lml", "predictive", "posterior"], "function")
    if fn == "lml":
        return gp.log_marginal_likelihood(xy, v, params)
    k = draw.integer(0, n, "split")
    if fn == "predictive":
        return gp.log_predictive(xy[:k], v[:k], xy[k:], v[k:], params)
    return gp.posterior(xy, v, xy[k:] if k < n else xy, params)


def hostile_tracks(draw: Draw) -> Any:
    """A tracks table with hostile ids, times and positions."""
    import pandas as pd

    n_tracks = draw.integer(1, 3, "tracks")
    lens = [draw.integer(1, 6, "len") for _ in range(n_tracks)]
    track = np.repeat(np.arange(n_tracks), lens)
    n = len(track)
    t0 = draw.choice([0.0, 1e9, 1e15, -5.0, 1e-9], "t0")
    step = draw.choice([0.1, 0.5, 1e-12, 1e3, 0.04], "step")
    t = t0 + np.concatenate([np.arange(m) * step for m in lens])
    df = pd.DataFrame({"track": track, "t": t, "x": scale_values(draw, n, "x"), "y": scale_values(draw, n, "y")})
    if draw.boolean("velocities", 0.4):
        df["vx"] = scale_values(draw, n, "vx")
        df["vy"] = scale_values(draw, n, "vy")
    for _ in range(draw.integer(0, 2, "damages")):
        col = draw.choice(list(df.columns) + ["scene"], "column")
        df[col] = draw.choice(
            [
                df[col].to_numpy()[::-1] if col in df else 0,
                np.full(n, NAN),
                np.full(n, "a"),
                np.full(n, None),
                np.zeros(n),
                np.arange(n) % 2,
                np.full(n, 2**62),
                np.array([[1, 2]] * n).tolist(),
            ],
            f"{col}.values",
        )
    return df


def frames_constructor_case(draw: Draw, ctx: Context) -> Any:
    """``dpgp.Frames(ids, offsets, xy, v)`` itself (as a user's code or a model file calls it),
    maybe with a NaN or inf among the positions or velocities (issue 36: it was accepted, and
    every score of that frame was NaN), then scored by the shared model."""
    frame, x, y, vx, vy = tiny_frames_arrays(draw)
    xy = _astype(np.column_stack([x, y]), float)
    v = _astype(np.column_stack([vx, vy]), float)
    if draw.boolean("non_finite", 0.6) and xy.dtype.kind == "f" and v.dtype.kind == "f":
        target = xy if draw.boolean("in_xy") else v
        target[draw.index(len(target)), draw.index(2)] = draw.choice([NAN, INF, -INF], "value")
    sizes = np.bincount(frame)
    frames = dpgp.Frames(np.arange(len(sizes)), np.r_[0, np.cumsum(sizes)], xy, v)
    model, _ = ctx.model
    use = draw.choice(["none", "score", "score_velocities", "proba"], "then")
    if use == "none":
        return frames
    if use == "proba":
        return model.predict_proba(frames)
    return model.score_samples(frames, positions=use == "score")


def case_framing(draw: Draw, ctx: Context, d: Path) -> Any:
    tracks = hostile_tracks(draw)
    if draw.boolean("via_read_tracks", 0.3):
        tracks = dpgp.read_tracks(tracks, sort=draw.boolean("sort"))
    fn = draw.choice([dpgp.make_frames, dpgp.make_frames, dpgp.resample_tracks], "function")
    p = draw.choice([0.0, 0.1, 0.35], "hostility")  # some cases with valid arguments only
    return fn(
        tracks,
        roi=draw.maybe(
            [None, (-1e9, 1e9, -1e9, 1e9), (0, 10, 0, 10)],
            [(1, 0, 0, 1), (NAN, 1, 0, 1), (0, INF, 0, 1), (0, 1), "roi", (0, 1, 0, "x"), 5],
            "roi",
            p,
        ),
        dt=draw.maybe([0.5, 0.1, 1.0], [0, -1, NAN, INF, 1e300, 1e-300, "x", None, 2**70], "dt", p),
        velocity=draw.maybe(["auto", "diff", "columns"], ["speed", None, 1], "velocity", p),
        smoothing=draw.maybe(
            [None, (3, 1), (5, 2)], [(2, 1), (3, 3), (3,), (-3, 1), (3, 1.5), (10**9, 1), "x", (3, -1)], "smoothing", p
        ),
        units=draw.maybe([None, "ft->m", 0.3048], [1e308, 1e-320, 0, -1, NAN, "km", "M->FT", True, 1e154], "units", p),
        max_gap=draw.maybe([None, 1.0], [0, -1, NAN, INF, 1e-300, "x"], "max_gap", p),
    )


SETTINGS = {
    # name: (valid values, hostile values)
    "iterations": ([0, 1], [-1, 1.5, "1", None, True, 2**64, -(2**63), NAN]),
    "assignment": (["gibbs", "map"], ["GIBBS", None, 3, ""]),
    "likelihood": (["exact", "auto", "hsgp"], ["approx", None, 1]),
    "length_scale_prior": (
        [(10.0, 1.0), (2.0, 0.5), "auto"],
        [
            (0, 1),
            (-1, 1),
            (NAN, 1),
            (1e308, 1e308),
            (1,),
            "ab",
            None,
            (1e-300, 1e-300),
            (INF, 1),
            *[(e, 1.0) for e in EXTREME[:5]],
            (1.0, 1e-300),
        ],
    ),
    "length_scales": (
        [None, (5.0, 5.0)],
        [
            (0, 1),
            (INF, 1),
            (1e-300, 1e-300),
            (1e300, 1e300),
            (-1, 1),
            "x",
            (NAN, NAN),
            *[(e, e) for e in EXTREME if e > 0],
        ],
    ),
    "noise_var": ([1.0, 0.5], [0, -1, NAN, INF, 1e-300, 1e300, "1", None, 1e-30, *[e for e in EXTREME if e > 0]]),
    "signal_var": (
        [None, 1.0, (2.0, 3.0)],
        [0, -1, NAN, INF, 1e300, 1e-300, "x", (1, 2, 3), *[e for e in EXTREME if e > 0]],
    ),
    "mean": ([None, 0.0, (1.0, -1.0)], [1e300, NAN, INF, -1e308, "x", (1,), *EXTREME[:6]]),
    "alpha": (
        [None, 1.0],
        [0, -1, NAN, INF, 1e-300, 1e300, "x", True, 1e308, 5e-324, 1e154, 1e-154, 1e100, 1e-100, 1e101],
    ),
    "new_pattern_samples": ([1, 3], [0, -1, 2**63, 2**64, 2**31, 1.5, "3", None, Unsafe(10**9)]),
    "length_scale_fraction": ([1.0, 0.5], [0, -1, NAN, 2, INF, "x", None, 5e-324, 1e-300]),
    "pattern_moments": ([False, True], ["yes", None, 2]),
    "seed": ([0, 7], [-1, 2**64, 2**70, "s", None, 1.5, -(2**70)]),
    # (n_threads=10**6 starts thousands of threads before failing: never in-process, see the runner)
    "n_threads": ([None, 1, 2], [0, -1, 2**64, "2", 1.5]),
    "n_iter_no_change": ([None, 1], [0, -1, NAN, "x", 1.5]),
    "ari_tol": ([0.99], [NAN, -1, 2, "x", 5e-324]),
    "store_labels": ([False, True], ["x", None]),
    "preset": ([None, "paper"], ["PAPER", 3, ""]),
    "proposal": (["informed", "full"], ["gibbs", None]),
    "sampler": (["auto", "subcluster", "collapsed"], ["gibbs", None, 3, "SUBCLUSTER"]),
    "init": (["sequential", "one", "many"], ["dispersed", None, 0, "random"]),
    "n_basis": ([None, (4, 4)], [(0, 0), (-1, 2), (10**9, 10**9), "x", (2.5, 3), 5]),
    "memory_budget": ([None], [0, -1, "x", 1, NAN, 2**70, "1 GB", 1e300, 5e-324]),
}


def hostile_settings(draw: Draw) -> dict[str, Any]:
    # noise_var="auto" (the default) needs 4 frames: tiny fits mostly name a number
    settings: dict[str, Any] = {"progress": False, "noise_var": draw.choice([1.0, 0.5, 2.0, 1.0, "auto"], "noise_var")}
    p = draw.choice([0.0, 0.05, 0.15], "hostility")
    for name, (valid, hostile) in SETTINGS.items():
        if draw.boolean(f"set_{name}", 0.5):
            settings[name] = draw.maybe(valid, hostile, name, p)
    return settings


def case_fit(draw: Draw, ctx: Context, d: Path) -> Any:
    frame, x, y, vx, vy = tiny_frames_arrays(draw)
    frames = dpgp.Frames.from_arrays(frame, x, y, vx, vy)
    model = dpgp.DPGP(**hostile_settings(draw))
    if isinstance(model.iterations, (int, np.integer)) and model.iterations > 1:
        model.iterations = 1  # keep fits tiny; a long fit is no defect
    if draw.boolean("checkpoint", 0.1):  # a checkpoint path as str, bytes or Path, maybe unwritable
        if draw.boolean("checkpoint_readonly", 0.5):
            with readonly_target(draw, d) as target:
                model.checkpoint = as_drawn_path(draw, target)
                return model.fit(frames)
        model.checkpoint = as_drawn_path(draw, d / "fit.ckpt")
    model.fit(frames)
    # A fitted model must also be usable: score, predict, query its field, simulate a few steps.
    use = draw.choice(["none", "proba", "score", "field", "simulate"], "then")
    if use == "proba":
        return model, model.predict_proba(frames)
    if use == "score":
        return model, model.score_samples(frames, positions=draw.boolean("positions"))
    if use == "field":
        return model, model.velocity_field(0, frames.xy)
    if use == "simulate":
        return model, model.simulate(0, steps=3, stochastic=draw.boolean("stochastic"), seed=1)
    return model


def _npz_members(data: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _npy_header(descr: str, shape: tuple[int, ...]) -> bytes:
    """An .npy member that is only a header declaring ``descr`` items of ``shape``."""
    header = repr({"descr": descr, "fortran_order": False, "shape": shape}).encode("latin1")
    header += b" " * (64 - (10 + len(header) + 1) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header


def _npy_with_shape(arr: np.ndarray, shape: tuple[int, ...]) -> bytes:
    """An .npy member whose header declares ``shape`` over ``arr``'s (short) data."""
    header = repr({"descr": np.lib.format.dtype_to_descr(arr.dtype), "fortran_order": False, "shape": shape})
    header = header.encode("latin1")
    pad = 64 - (10 + len(header) + 1) % 64
    header += b" " * pad + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header + arr.tobytes()


META_PATHS = [
    ("alpha",),
    ("format_version",),
    ("format",),
    ("settings",),
    ("params",),
    ("history",),
    ("n_iter",),
    ("frames_summary",),
    ("distributions",),
    ("settings", "iterations"),
    ("settings", "new_pattern_samples"),
    ("settings", "seed"),
    ("settings", "noise_var"),
    ("settings", "length_scale_prior"),
    ("settings", "alpha"),
    ("settings", "assignment"),
    ("settings", "n_threads"),
    ("settings", "length_scales"),
    ("settings", "bogus"),
    ("settings", "length_scale_fraction"),
    ("settings", "mean"),
    ("settings", "signal_var"),
    ("params", "length_scales"),
    ("params", "signal_var"),
    ("params", "noise_var"),
    ("params", "mean"),
    ("history", "log_joint"),
    ("history", "alpha"),
    ("frames_summary", "dt"),
    ("frames_summary", "roi"),
    ("distributions", "count_hist"),
    ("distributions", "position_hist"),
    ("distributions", "roi"),
    ("distributions", "version"),
    ("distributions", "pseudocount"),
    ("distributions", "count_pseudocount"),
    ("distributions", "position_pseudocount"),
    ("timings",),
    ("converged",),
    ("resume",),
    ("resume", "sweeps_done"),
    ("resume", "stable"),
    ("resume", "alpha"),
    ("resume", "data_sha256"),
    ("settings", "checkpoint"),
    ("settings", "checkpoint_every"),
    ("resolved", "noise_var"),
    ("resolved", "length_scale_prior"),
    ("params", "length_scales"),
]
META_VALUES = [
    None,
    -1,
    0,
    1,
    1e308,
    -1e308,
    1e-320,
    "x",
    [],
    {},
    [1, 2, 3],
    True,
    2**63,
    2**70,
    NAN,
    INF,
    -INF,
    [NAN, 1.0],
    [[1.0]],
    [1e308, 1e308],
    [0.0, 0.0],
    "DELETE",
    "DEEP",
    *EXTREME,
    [1e154, 1e154],
    [5e-324, 5e-324],
    [1e200, 1.0],
    [1e-200, 1e-200],
]


def damaged_model_file(draw: Draw, ctx: Context, d: Path) -> Path:
    # A model file, or a checkpoint (a model file with a resume point: DPGP(checkpoint=...)).
    base = ctx.checkpoint if draw.boolean("checkpoint", 0.3) else ctx.model[1]
    path = d / draw.choice(["model.npz", "model", "model.npy"], "name")
    how = draw.choice(
        ["truncate", "flip", "metadata", "metadata", "member", "member", "shape", "huge", "foreign", "shift"], "damage"
    )
    data = base
    if how == "truncate":
        data = base[: draw.integer(0, len(base) - 1, "at")]
    elif how == "flip":
        buf = bytearray(base)
        for _ in range(draw.integer(1, 16, "bits")):
            buf[draw.index(len(buf))] ^= 1 << draw.integer(0, 7, "bit")
        data = bytes(buf)
    elif how == "huge":
        # A member declaring a huge array (issue 17): of zero-byte items (it reads as nothing,
        # then converts to 745 GiB), or of real items past the data held.
        arrays = _npz_members(base)
        name = draw.choice(sorted(arrays), "member")
        descr = draw.choice(["|V0", "<U0", "|S0", "<f8", "<i8"], "descr")
        shape = draw.choice([(10**11,), (10**11, 2), (2**40,), (10**11, 0), (0, 10**11)], "shape")
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w") as z:
            for k, v in arrays.items():
                raw = io.BytesIO()
                np.save(raw, v, allow_pickle=False)
                z.writestr(k + ".npy", _npy_header(descr, shape) if k == name else raw.getvalue())
        data = buf.getvalue()
    elif how == "shift":
        # the stored frames moved by up to a few bins of ψ (issue 36: their own scores were -inf)
        arrays = _npz_members(base)
        arrays["frame_xy"] = arrays["frame_xy"] + np.array(
            [draw.uniform(-15.0, 15.0, "dx"), draw.uniform(-15.0, 15.0, "dy")]
        )
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        data = buf.getvalue()
    elif how in ("metadata", "member", "shape"):
        arrays = _npz_members(base)
        if how == "metadata":
            meta = json.loads(str(arrays["metadata"]))
            for _ in range(draw.integer(1, 2, "edits")):
                keys = draw.choice(META_PATHS, "key")
                value = draw.choice(META_VALUES, "value")
                node = meta
                for k in keys[:-1]:
                    node = node.setdefault(k, {}) if isinstance(node, dict) else {}
                if not isinstance(node, dict):
                    continue
                if value == "DELETE":
                    node.pop(keys[-1], None)
                elif value == "DEEP":
                    node[keys[-1]] = "DEEP"
                else:
                    node[keys[-1]] = value
            text = json.dumps(meta)
            text = text.replace('"DEEP"', "[" * 100_000 + "]" * 100_000)
            arrays["metadata"] = np.array(text)
        elif how == "member":
            name = draw.choice(sorted(arrays) + ["frame_labels", "label_trace"], "member")
            old = arrays.get(name, np.zeros(3))
            arrays[name] = draw.choice(
                [
                    old[:-1] if old.ndim else old,
                    old[::-1].copy() if old.ndim else old,
                    old.astype(np.float32) if old.dtype.kind != "U" else old,
                    old.astype(str),
                    np.zeros((0,)),
                    np.full(old.shape, NAN),
                    -np.abs(old.astype(float)) if old.dtype.kind in "iuf" else old,
                    np.array(5),
                    np.zeros((2, 3, 4)),
                    old.astype(complex) if old.dtype.kind in "iuf" else old,
                    np.full(old.shape, 2**62, dtype=np.int64),
                    np.array(["x"] * max(1, len(old) if old.ndim else 1)),
                    np.full(old.shape, 1e308) if old.dtype.kind in "iuf" else old,
                    "DELETE",
                    *[old * e if old.dtype.kind == "f" else old for e in (1e154, 1e200, 1e-200, 5e-324, 1e99)],
                ],
                "replacement",
            )
            if isinstance(arrays[name], str):
                del arrays[name]
        buf = io.BytesIO()
        if how == "shape":
            name = draw.choice(
                ["frame_xy", "frame_v", "labels", "length_scales", "frame_offsets", "frame_ids"], "member"
            )
            shape = draw.choice(
                [(2**40, 2), (10**18,), (2**31, 2**31), (0, 2), (3,), (-1, 2), (2**62, 2**62, 2)], "shape"
            )
            with zipfile.ZipFile(buf, "w") as z:
                for k, v in arrays.items():
                    raw = io.BytesIO()
                    np.save(raw, v, allow_pickle=False)
                    z.writestr(k + ".npy", _npy_with_shape(v, shape) if k == name else raw.getvalue())
        else:
            save = np.savez_compressed if draw.boolean("compressed") else np.savez
            save(buf, **arrays)
        data = buf.getvalue()
    else:
        kind = draw.choice(["empty", "random", "text", "npy", "gz", "zip_text", "dir"], "foreign")
        if kind == "dir":
            path.mkdir()
            return path
        data = {
            "empty": b"",
            "random": bytes(
                np.random.default_rng(draw.integer(0, 99, "bytes_seed")).integers(0, 256, 300, dtype=np.uint8)
            ),
            "text": b"frame,x,y,vx,vy\n0,1,2,3,4\n",
            "gz": gzip.compress(base),
        }.get(kind, b"")
        if kind == "npy":
            raw = io.BytesIO()
            np.save(raw, np.arange(4.0))
            data = raw.getvalue()
        elif kind == "zip_text":
            raw = io.BytesIO()
            with zipfile.ZipFile(raw, "w") as z:
                z.writestr("metadata.npy", "not numpy")
            data = raw.getvalue()
    path.write_bytes(data)
    return path


def as_drawn_path(draw: Draw, path: Path) -> Any:
    """``path`` as str, bytes or a Path: every place that takes a path takes all three."""
    kind = draw.choice(["path", "str", "bytes"], "path_type")
    return {"path": path, "str": str(path), "bytes": os.fsencode(str(path))}[kind]


@contextlib.contextmanager
def readonly_target(draw: Draw, d: Path):
    """A save target that cannot be written as asked (issue 17): a read-only file, a read-only
    or append-only directory (``chattr +a``: a file can be created there but neither renamed nor
    removed), or an existing directory. The flags are cleared afterwards so the case's
    directory can go."""
    kind = draw.choice(["readonly_file", "readonly_dir", "append_only_dir", "immutable_file", "dir"], "target")
    sub = d / "target"
    sub.mkdir()
    target = sub / "model.npz"
    undo: list[Callable[[], Any]] = []
    if kind in ("readonly_file", "immutable_file"):
        target.write_bytes(b"old")
        if kind == "readonly_file":
            target.chmod(0o444)
        elif _chattr("+i", target):
            undo.append(lambda: _chattr("-i", target))
    elif kind == "readonly_dir":
        sub.chmod(0o555)
        undo.append(lambda: sub.chmod(0o755))
    elif kind == "append_only_dir" and _chattr("+a", sub):
        undo.append(lambda: _chattr("-a", sub))
    elif kind == "dir":
        target.mkdir()
    try:
        yield target
    finally:
        for f in undo:
            f()


def _chattr(flag: str, path: Path) -> bool:
    import subprocess

    try:
        return subprocess.run(["chattr", flag, str(path)], capture_output=True, timeout=10).returncode == 0
    except (OSError, subprocess.SubprocessError):
        return False


def case_model_files(draw: Draw, ctx: Context, d: Path) -> Any:
    path = as_drawn_path(draw, damaged_model_file(draw, ctx, d))
    if draw.boolean("resume", 0.2):
        # Continues the chain (and checkpoints to the damaged file's path); a plain model file
        # is a typed error. Always a small total: None would finish the file's own iterations,
        # which an edit may make 2**63 (a long fit, not a defect).
        iterations = draw.maybe([3, 4], [-1, 2, "5", 1.5, True, [4]], "iterations")
        return dpgp.DPGP.resume(path, iterations=iterations)
    if draw.boolean("metadata_only", 0.15):
        from dpgp.io import read_metadata

        read_metadata(path)  # the raw metadata, as stored: only its reading is checked
        return None
    model = dpgp.DPGP.load(path)
    use = draw.choice(
        ["proba", "score", "field", "simulate", "scenarios", "save", "save_over_dir", "save_readonly", "cond"], "then"
    )
    frames = model.frames_[:1]
    if use == "proba":
        return model, model.predict_proba(frames)
    if use == "score":
        return model, model.score_samples(frames)
    if use == "field":
        return model, model.velocity_field(0, frames.xy)
    if use == "simulate":
        return model, model.simulate(0, steps=3)
    if use == "scenarios":
        return model, model.sample_scenarios(2, steps=3, seed=0)
    if use == "cond":  # masked: frame 0's own pattern when it holds only frame 0 (as in model_use)
        return model, model.conditional_log_probs(0)
    if use == "save_readonly":
        with readonly_target(draw, d) as target:
            model.save(as_drawn_path(draw, target))
        return model
    target = d / "again.npz"
    if use == "save_over_dir":
        target.mkdir()  # the final rename fails: the temporary file must go
    model.save(target)
    return model


def hostile_frame_arg(draw: Draw, model: Any) -> Any:
    n = len(model.frames_)
    return draw.maybe(
        [
            0,
            1,
            -1,
            model.frames_[0],
            model.frames_[1:2],
            np.array([[0.0, 0.0], [5.0, 5.0]]),
            np.array([[1.0, 2.0, 3.0, 4.0]]),
        ],
        [
            n,
            -n - 1,
            2**63,
            True,
            1.5,
            None,
            "0",
            np.zeros((0, 2)),
            np.zeros((2, 3)),
            np.array([[NAN, 0.0]]),
            np.array([[1e308, 1e308]]),
            np.array([[1e154, -1e154, 1e154, 1.0]]),
            [[0, 0]],
            model.frames_,
            np.array([[6e6, 6e6]]),
            np.zeros((3,)),
        ],
        "frame",
    )


def case_model_use(draw: Draw, ctx: Context, d: Path) -> Any:
    model, _ = ctx.model
    op = draw.choice(
        [
            "predict",
            "predict_proba",
            "score_samples",
            "velocity_field",
            "simulate",
            "simulate",
            "sample_scenarios",
            "sample_scenarios",
            "conditional_log_probs",
        ],
        "method",
    )
    if op in ("predict", "predict_proba", "score_samples"):
        frames = draw.choice(["train", "arrays", "df", "none", "list", "str", "shifted"], "frames")
        if frames == "train":
            arg = model.frames_
        elif frames == "shifted":  # the training frames moved by up to a few bins of ψ, past its edge
            shift = np.array([draw.uniform(-15.0, 15.0, "dx"), draw.uniform(-15.0, 15.0, "dy")])
            f = model.frames_
            arg = dpgp.Frames(f.ids, f.offsets, f.xy + shift, f.v)
        elif frames in ("arrays", "df"):
            f, x, y, vx, vy = tiny_frames_arrays(draw)
            arg = dpgp.Frames.from_arrays(f, x, y, vx, vy)
            if frames == "df":
                arg = arg.to_pandas()
        else:
            arg = {"none": None, "list": [[0, 1, 2, 3, 4]], "str": "frames.csv"}[frames]
        return getattr(model, op)(arg)
    if op == "velocity_field":
        k = draw.maybe(
            [0, model.n_patterns_ - 1], [-1, model.n_patterns_, 0.0, None, "0", 2**64, True, np.int64(0), 1.5], "k"
        )
        xy = draw.maybe(
            [[[0.0, 0.0]], np.zeros((3, 2))],
            [
                None,
                [],
                [0, 0],
                [[NAN, 0]],
                [[1e308, 1e308]],
                [[1e154, 1e154]],
                np.zeros((0, 2)),
                "xy",
                [[6e6, 6e6]],
                np.zeros((2, 3)),
                [[1 + 1j, 0]],
            ],
            "xy",
        )
        return model.velocity_field(k, xy)
    if op == "conditional_log_probs":
        return model.conditional_log_probs(draw.maybe([0, 3], [-1, 12, None, 1.5, "0", 2**64], "i"))
    steps = draw.maybe([0, 1, 5], [-1, 1.5, None, "3", 2**63, Unsafe(2 * 10**8), Unsafe(10**7)], "steps")
    dt = draw.maybe([None, 0.1, 1.0], [0, -1, NAN, INF, 1e300, 1e-300, "x", 2**1000], "dt")
    method = draw.maybe(["euler", "rk4"], ["RK4", None, 4], "method")
    seed = draw.maybe([None, 0, 5], [-1, 2**64, "s", 1.5], "seed")
    roi = draw.maybe(
        [None, (-60, 60, -60, 60)],
        [(1, 0, 0, 1), (NAN, 0, 0, 1), (0, 1), "roi", (-INF, INF, -INF, INF), (0, 1e-300, 0, 1e-300)],
        "roi",
    )
    thr = draw.maybe([0.5, None], [-1, NAN, INF, "x"], "low_data_threshold")
    if op == "simulate":
        pattern = draw.maybe([None, 0], [-1, model.n_patterns_, 1.5, "0"], "pattern")
        return model.simulate(
            hostile_frame_arg(draw, model),
            pattern=pattern,
            steps=steps,
            dt=dt,
            method=method,
            stochastic=draw.boolean("stochastic"),
            seed=seed,
            roi=roi,
            low_data_threshold=thr,
        )
    n = draw.maybe([0, 1, 3], [-1, 1.5, None, "2", 2**63, Unsafe(10**8)], "n")
    pattern = draw.maybe([None, 0], [-1, model.n_patterns_, 1.5, "0"], "pattern")
    return model.sample_scenarios(
        n,
        steps=steps,
        pattern=pattern,
        seed=seed,
        dt=dt,
        method=method,
        stochastic=draw.boolean("stochastic"),
        roi=roi,
        low_data_threshold=thr,
    )


# --- the CLI ---------------------------------------------------------------------------------------
def _cli_number(draw: Draw, valid: Sequence[str], hostile: Sequence[str], label: str) -> str:
    return draw.maybe(list(valid), list(hostile), label)


HOSTILE_NUM_TEXT = ["-1", "0", "nan", "inf", "-inf", "1e309", "x", "", "1.5", "99999999999999999999999", "--", "-0"]


def cli_argv(draw: Draw, ctx: Context, d: Path) -> list[str]:
    cmd = draw.choice(
        ["fit", "fit", "info", "simulate", "generate", "plot", "demo", "bogus", "none", "resume"], "command"
    )
    model_path = str(d / "model.npz")
    _, base = ctx.model
    if cmd in ("info", "simulate", "generate", "plot", "resume"):
        state = draw.choice(["good", "good", "damaged", "missing", "dir"], "model")
        if state == "good":
            Path(model_path).write_bytes(base)
        elif state == "damaged":
            model_path = str(damaged_model_file(draw, ctx, d))
        elif state == "dir":
            model_path = str(d)
    if cmd == "none":
        return []
    if cmd == "bogus":
        return [draw.choice(["bogus", "--version", "-h", "FIT", ""], "word")]
    out = str(d / draw.choice(["out.csv", "out.npz", "out.xml", "out.xml.gz", "missing/out.csv", "", "."], "output"))
    if cmd == "fit":
        frame, x, y, vx, vy = (
            tiny_frames_arrays(draw)
            if draw.boolean("hostile_data", 0.5)
            else (
                np.repeat(np.arange(3), 3),
                np.arange(9.0),
                np.arange(9.0) % 4,
                np.ones(9) + np.arange(9) % 2,
                np.arange(9.0) % 3,
            )
        )
        import pandas as pd

        data = d / "frames.csv"
        kind = draw.choice(["frames", "frames", "real", "missing", "empty", "dir"], "data")
        if kind == "frames":
            pd.DataFrame({"frame": frame, "x": x, "y": y, "vx": vx, "vy": vy}).to_csv(data, index=False)
        elif kind == "real":
            data = write_corrupted(draw, ctx, d, draw.choice(sorted(ctx.data), "file"))
        elif kind == "empty":
            data.write_bytes(b"")
        elif kind == "dir":
            data = d
        argv = ["fit", str(data), "-o", out]
        if draw.boolean("roi", 0.3):
            argv += ["--roi"] + [draw.maybe(["-1e9", "1e9", "0", "10"], HOSTILE_NUM_TEXT, "roi") for _ in range(4)]
        for flag, valid, hostile in [
            ("--dt", ["0.5", "1"], HOSTILE_NUM_TEXT + ["1e300", "1e-300"]),
            ("--units", ["ft->m", "1"], ["km", "0", "-1", "nan", "1e308", "x"]),
            ("--iterations", ["0", "1"], ["-1", "x", "1.5"]),
            ("--assignment", ["map", "gibbs"], ["MAP", ""]),
            ("--alpha", ["1"], HOSTILE_NUM_TEXT + ["1e308"]),
            ("--max-frames", ["1", "2"], ["0", "-1", "x"]),
            ("--threads", ["1"], ["0", "-1", "99999999999999999999"]),
            ("--seed", ["3"], ["-1", "99999999999999999999999", "x"]),
            ("--format", ["auto", "frames", "tracks"], ["ngsim", "sumo", "eth_ucy", "bogus"]),
        ]:
            if draw.boolean(flag, 0.25):
                argv += [flag, draw.maybe(valid, hostile, flag)]
        if "--iterations" not in argv:
            argv += ["--iterations", "1"]
        return argv + (["--no-progress"] if draw.boolean("quiet", 0.9) else [])
    if cmd == "info":
        return ["info", model_path] + (
            ["--top", _cli_number(draw, ["3"], HOSTILE_NUM_TEXT + ["1000000000"], "top")] if draw.boolean("top") else []
        )
    if cmd == "resume":
        if draw.boolean("checkpoint") and Path(model_path).is_file():
            Path(model_path).write_bytes(ctx.checkpoint)
        # Always --iterations: without it the chain runs to the file's own, which an edit may make 2**63.
        argv = [
            "resume",
            model_path,
            "--no-progress",
            "--iterations",
            _cli_number(draw, ["3", "5"], ["-1", "0", "x", "1.5", ""], "iterations"),
        ]
        return argv + (["-o", out] if draw.boolean("-o", 0.5) else [])
    if cmd == "simulate":
        argv = [
            "simulate",
            model_path,
            "--frame",
            _cli_number(draw, ["0", "1", "-1"], HOSTILE_NUM_TEXT + ["1000000"], "frame"),
            "-o",
            out,
        ]
        for flag, valid, hostile in [
            ("--pattern", ["0"], ["-1", "99", "x"]),
            ("--steps", ["0", "3"], ["-1", "x", "1.5"] + ([] if draw.safe else ["200000000"])),
            ("--dt", ["0.5"], HOSTILE_NUM_TEXT + ["1e300"]),
            ("--method", ["rk4"], ["RK4"]),
            ("--seed", ["1"], ["-1", "99999999999999999999999"]),
        ]:
            if draw.boolean(flag, 0.3):
                argv += [flag, draw.maybe(valid, hostile, flag)]
        if "--steps" not in argv:
            argv += ["--steps", "3"]
        return argv + (["--stochastic"] if draw.boolean("stochastic") else [])
    if cmd == "generate":
        argv = ["generate", model_path, "-n", _cli_number(draw, ["0", "2"], HOSTILE_NUM_TEXT, "n"), "-o", out]
        for flag, valid, hostile in [
            ("--format", ["csv", "sumo"], ["xml"]),
            ("--steps", ["0", "3"], ["-1", "x"]),
            ("--pattern", ["0"], ["-1", "99"]),
            ("--dt", ["0.5"], HOSTILE_NUM_TEXT),
            ("--method", ["rk4"], ["x"]),
            ("--seed", ["1"], ["-1", "99999999999999999999999"]),
        ]:
            if draw.boolean(flag, 0.3):
                argv += [flag, draw.maybe(valid, hostile, flag)]
        if "--steps" not in argv:
            argv += ["--steps", "3"]
        return argv + (["--mean"] if draw.boolean("mean") else [])
    if cmd == "plot":
        argv = [
            "plot",
            model_path,
            "--out",
            str(d / draw.choice(["figs", "model.npz", ""], "out")),
            "--kind",
            draw.choice(["weights", "trace", "field", "bogus"], "kind"),
        ]
        for flag, valid, hostile in [
            ("--patterns", ["1"], ["-1", "0", "x"]),
            ("--frame", ["0"], ["-1", "1000000", "x"]),
            ("--steps", ["2"], ["-1", "x"]),
            ("--dpi", ["20"], ["0", "-1", "x", "nan"]),
        ]:
            if draw.boolean(flag, 0.3):
                argv += [flag, draw.maybe(valid, hostile, flag)]
        return argv
    # demo: only hostile arguments that must fail before any work (a full demo takes seconds)
    return [
        "demo",
        "--out",
        str(d / "demo"),
        "--frames",
        draw.choice(["0", "-1", "x", "nan"], "frames"),
        "--iterations",
        draw.choice(["0", "-1", "x"], "iterations"),
        "--no-progress",
    ]


_PROGRESS = __import__("re").compile(r"^dpgp (sweeps|chains): +\d+%\|")


def case_cli(draw: Draw, ctx: Context, d: Path) -> Outcome:
    from dpgp.cli import main

    argv = cli_argv(draw, ctx, d)
    out, err = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main(argv)
    except SystemExit as e:  # argparse exits; main should return instead
        code = e.code if isinstance(e.code, int) else 1
        if code != 0:
            return Outcome(
                "cli", f"main raised SystemExit({e.code!r}) instead of returning | stderr {err.getvalue()[-200:]!r}"
            )
        return Outcome("valid", "exit 0")
    except BaseException as e:
        return Outcome("cli", f"main raised {type(e).__name__} at {where(e)}: {' '.join(str(e).split())[:160]}")
    text = err.getvalue()
    if "Traceback" in text:
        return Outcome("cli", f"traceback printed: {text[-300:]!r}")
    if code == 0:
        return Outcome("valid", "exit 0")
    # Progress bars (tqdm redraws with \r, "dpgp sweeps: ...") are not error lines.
    lines = [line for line in text.replace("\r", "\n").splitlines() if line.strip() and not _PROGRESS.match(line)]
    if not isinstance(code, int):
        return Outcome("cli", f"main returned {code!r}, not an exit status")
    if len(lines) != 1 or not lines[0].startswith("dpgp"):
        return Outcome("cli", f"exit {code} with {len(lines)} line(s) of error: {text[-300:]!r}")
    if "internal error" in lines[0]:
        return Outcome("cli", f"exit {code}: {lines[0][:200]}")
    return Outcome("typed", f"exit {code}: {lines[0][:160]}")


CASES: dict[str, Callable[[Draw, Context, Path], Any]] = {
    "readers": case_readers,
    "arrays": case_arrays,
    "framing": case_framing,
    "fit": case_fit,
    "model_files": case_model_files,
    "model_use": case_model_use,
    "cli": case_cli,
}


def run_case(surface: str, draw: Draw, ctx: Context) -> Outcome:
    """Run one case of ``surface`` and classify what happened."""
    import warnings

    d = ctx.case_dir()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                result = CASES[surface](draw, ctx, d)
            except Exception as e:  # noqa: BLE001 - classifying every exception is the point
                outcome = classify_exception(e)
            else:
                if isinstance(result, Outcome):
                    outcome = result
                else:
                    value, allow = (
                        result
                        if isinstance(result, tuple) and len(result) == 2 and isinstance(result[1], bool)
                        else (result, False)
                    )
                    try:
                        bad = nonfinite(value, allow)
                    except Exception as e:  # noqa: BLE001 - a result too malformed to inspect
                        outcome = Outcome("untyped", f"malformed result ({type(e).__name__} at {where(e)}: {e})")
                    else:
                        outcome = Outcome("nonfinite", bad) if bad else Outcome("valid")
        left = [p.name for p in d.rglob(".dpgp-*")]
        if left and not outcome.defect:
            outcome = Outcome("tempfile", f"left behind: {left}")
        return outcome
    finally:
        shutil.rmtree(d, ignore_errors=True)


def signature(surface: str, outcome: Outcome) -> str:
    """A short key that groups cases with the same defect (type and place, not the values)."""
    detail = outcome.detail
    if outcome.kind in ("untyped", "cli") and " at " in detail:
        head, _, rest = detail.partition(" at ")
        return f"{surface}/{outcome.kind}: {head} at {rest.split(':')[0]}:{rest.split(':')[1] if ':' in rest else ''}"
    if outcome.kind == "cli":
        detail = detail.split(" | ")[0].split(":")[0]
    return f"{surface}/{outcome.kind}: {detail[:90]}"
