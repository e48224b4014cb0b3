"""The package's import graph (docs/layout.md): every module imports only from its own layer or
below, and no module imports one that imports it back (no circle, lazy imports included).

Every import statement counts, at module level or inside a function or ``if TYPE_CHECKING``: a
lazy import still makes the lower module depend on the higher one. Run with ``-s`` to see the
graph (``python -m pytest tests/test_layout.py -s``)."""

from __future__ import annotations

import ast
import textwrap
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "python" / "dpgp"

#: Bottom to top. A top-level private module (and ``exceptions``) is the base; a stage is a
#: subpackage; ``plot``, ``cli`` and the package ``__init__`` are the top.
LAYERS = ["base", "data", "gp", "generate", "evaluate", "io", "model", "chains", "top"]
TOP = {"plot", "cli", "__init__"}


def layer_of(module: str) -> int:
    """The layer of a dotted module name below the package (``data.frames``, ``_arrays``, ``__init__``)."""
    first = module.split(".")[0]
    if first in TOP:
        return LAYERS.index("top")
    if first in LAYERS:
        return LAYERS.index(first)
    return LAYERS.index("base")  # exceptions, _version, _arrays, _core, ...


def _modules(root: Path) -> dict[str, Path]:
    """Dotted names (``data.frames``; a package is ``data.__init__``) of every module under ``root``."""
    out = {}
    for path in root.rglob("*.py"):
        out[".".join(path.relative_to(root).with_suffix("").parts)] = path
    for path in root.glob("*.pyi"):  # the binding: a stub beside a built extension
        out.setdefault(path.stem, path)
    return out


def _resolve(name: str, modules: dict[str, Path]) -> str | None:
    """The module file ``name`` (dotted, below the package) stands for: a module, or a package's
    ``__init__``; None outside the package."""
    if name in modules:
        return name
    if f"{name}.__init__" in modules or name == "":
        return f"{name}.__init__".lstrip(".")
    return None


def imports(root: Path, package: str = "dpgp") -> dict[str, set[str]]:
    """Each module's imports of modules of the same package, as dotted names below it."""
    modules = _modules(root)
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        if path.suffix == ".pyi":
            graph[name] = set()
            continue
        parts = name.split(".")
        pkg = parts[:-1]  # the package a relative import starts from (for __init__ too: its own)
        targets: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name == package or alias.name.startswith(package + "."):
                        targets.add(_resolve(alias.name[len(package) + 1 :], modules) or "__init__")
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = pkg[: len(pkg) - (node.level - 1)] if node.level > 1 else pkg
                    module = ".".join(base + ([node.module] if node.module else []))
                elif node.module and (node.module == package or node.module.startswith(package + ".")):
                    module = node.module[len(package) + 1 :]
                else:
                    continue
                for alias in node.names:  # `from . import frames` imports a module, not a name
                    sub = f"{module}.{alias.name}".lstrip(".")
                    target = _resolve(sub, modules) if (sub in modules or f"{sub}.__init__" in modules) else None
                    targets.add(target or _resolve(module, modules) or module)
        targets.discard(name)
        graph[name] = targets
    return graph


def upward(graph: dict[str, set[str]]) -> list[str]:
    """Imports of a higher layer, as ``a -> b (layer -> layer)``."""
    return sorted(
        f"{a} -> {b} ({LAYERS[layer_of(a)]} -> {LAYERS[layer_of(b)]})"
        for a, targets in graph.items()
        for b in targets
        if layer_of(b) > layer_of(a)
    )


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(found)


def test_no_module_imports_upward():
    graph = imports(PACKAGE)
    print("\n".join(f"{a} ({LAYERS[layer_of(a)]}) -> {', '.join(sorted(graph[a])) or '-'}" for a in sorted(graph)))
    assert upward(graph) == []


def test_no_import_circles():
    assert circles(imports(PACKAGE)) == []


def test_every_stage_is_a_package_of_the_layer_table():
    stages = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").exists()}
    assert stages == set(LAYERS) - {"base", "top"}


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    root = tmp_path / "dpgp"
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))
    return root


def test_the_checker_finds_a_planted_upward_import_and_circle(tmp_path):
    root = _tree(
        tmp_path,
        {
            "__init__.py": "from .model import DPGP\n",
            "exceptions.py": "",
            "_arrays.py": "from .exceptions import ShapeError\n",
            "data/__init__.py": "",
            "data/frames.py": "def f():\n    from ..model.estimator import DPGP  # lazy, still upward\n",
            "gp/__init__.py": "from . import exact\n",
            "gp/exact.py": "from .. import _arrays\nfrom .hsgp import Basis\n",
            "gp/hsgp.py": "import dpgp.gp.exact\n",
            "model/__init__.py": "from .estimator import DPGP\n",
            "model/estimator.py": "from ..data.frames import Frames\nfrom dpgp.gp import exact\n",
        },
    )
    graph = imports(root)
    assert graph["gp.exact"] == {"_arrays", "gp.hsgp"} and graph["model.estimator"] == {"data.frames", "gp.exact"}
    assert upward(graph) == ["data.frames -> model.estimator (data -> model)"]
    assert circles(graph) == [["data.frames", "model.estimator"], ["gp.exact", "gp.hsgp"]]


def test_the_checker_passes_a_clean_tree(tmp_path):
    root = _tree(
        tmp_path,
        {
            "__init__.py": "from . import plot\nfrom .data import frames\n",
            "plot.py": "from .data.frames import Frames\nfrom . import exceptions\n",
            "exceptions.py": "",
            "data/__init__.py": "from . import frames\n",
            "data/frames.py": "from ..exceptions import ShapeError\n",
        },
    )
    graph = imports(root)
    assert graph["plot"] == {"data.frames", "exceptions"} and graph["data.__init__"] == {"data.frames"}
    assert upward(graph) == [] and circles(graph) == []
