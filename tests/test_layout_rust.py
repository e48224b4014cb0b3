"""The Rust core's modules import only downward: no module of `rust/core/src` uses one that uses it
back, directly or through others. Read from the sources (`crate::name` paths), not from a build."""

from __future__ import annotations

import re
from pathlib import Path

from test_layout import circles  # the package's own circle finder (Tarjan), shared

CORE = Path(__file__).resolve().parents[1] / "rust" / "core" / "src"
_PATH = re.compile(r"\bcrate::(\w+)")
_GROUP = re.compile(r"\bcrate::\{([^}]*)\}")


def _code(text: str) -> str:
    """The source without comments (a doc comment may name a module it does not use)."""
    return "\n".join(line.split("//", 1)[0] for line in text.splitlines())


def module_graph(src: Path) -> dict[str, set[str]]:
    """module -> the crate's modules it names. `tests/` and `lib.rs` are not modules of the layering."""
    mods = {p.stem for p in src.glob("*.rs") if p.stem != "lib"}
    graph = {}
    for m in mods:
        code = _code((src / f"{m}.rs").read_text())
        used = set(_PATH.findall(code))
        for group in _GROUP.findall(code):
            used |= {part.strip().split("::")[0] for part in group.split(",") if part.strip()}
        graph[m] = {u for u in used if u in mods and u != m}
    return graph


def test_the_core_has_no_module_circle() -> None:
    graph = module_graph(CORE)
    assert len(graph) > 10, "the core's sources were not found"
    assert circles(graph) == []


def test_the_checker_finds_a_planted_circle(tmp_path: Path) -> None:
    (tmp_path / "lib.rs").write_text("pub mod a; pub mod b; pub mod c;\n")
    (tmp_path / "a.rs").write_text("use crate::b::B;\n// crate::c is only named in a comment\n")
    (tmp_path / "b.rs").write_text("use crate::{c::C, error::Error};\n")
    (tmp_path / "c.rs").write_text("pub struct C;\n")
    assert circles(module_graph(tmp_path)) == []
    (tmp_path / "c.rs").write_text("pub fn f() -> crate::a::A { todo!() }\n")
    assert circles(module_graph(tmp_path)) == [["a", "b", "c"]]
