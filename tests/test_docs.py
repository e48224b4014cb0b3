"""The README front page and the docs tables: links resolve, the commands are CI's, tables are stamped.

The site itself is built with warnings as errors by ``.ci/run`` (``mkdocs build --strict``), which
checks the links and anchors between docs pages and renders the API reference; these tests
cover what mkdocs does not see: the README, which lives outside ``docs/``.
"""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


def _links(path: Path) -> list[str]:
    return re.findall(r"\]\(([^)\s]+)\)", path.read_text(encoding="utf-8"))


def _bash_blocks(path: Path) -> list[str]:
    return re.findall(r"```bash\n(.*?)```", path.read_text(encoding="utf-8"), flags=re.S)


def test_readme_links_resolve():
    local = [link for link in _links(README) if not re.match(r"[a-z]+:", link)]
    assert local, "the README links into the docs"
    missing = [link for link in local if not (ROOT / link.split("#")[0]).exists()]
    assert missing == []


def test_readme_is_a_front_page():
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 120
    examples = re.findall(r"```(?:python|bash)\n(.*?)```", text, flags=re.S)
    assert not [e for e in examples if "shared/data" in e], "a pip user does not have the project's shared data"


def test_readme_commands_are_the_demo_then_what_ci_runs():
    blocks = [b.strip() for b in _bash_blocks(README)]
    assert blocks[0] == "pip install . && dpgp demo"
    install, tests = blocks[1].split(" && ", 1)
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    # CI runs the same install and the same tests (as python3 -m ..., with checks in between),
    # each test command on its own line: under `set -e` a failure left of `&&` would not stop it
    assert f"python3 -m {install}\n" in ci
    for command in tests.split(" && "):
        assert f"\n{command.replace('python -m', 'python3 -m')}\n" in ci, command


def _tables():
    spec = importlib.util.spec_from_file_location("bench_tables", ROOT / "benches" / "tables.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_markdown_table_formats_rows():
    tables = _tables()
    text = tables.markdown_table(
        [{"a": 1, "b": 0.123456, "c": None}, {"a": "x|y", "b": 12345.6, "c": float("nan")}], ["a", "b", "c"]
    )
    assert text.splitlines() == ["| a | b | c |", "|---|---|---|", "| 1 | 0.123 | — |", "| x\\|y | 12,346 | — |"]


def test_stamp_names_commit_machine_and_command(tmp_path):
    tables = _tables()
    page = tmp_path / "t.md"
    tables.write_page(page, "T", "intro", "| a |\n|---|\n| 1 |", "python benches/x.py", date="2026-01-01 00:00 UTC")
    text = page.read_text()
    assert text.startswith("# T\n\nintro\n\n| a |")
    stamp = text.split("| 1 |", 1)[1]
    assert "`python benches/x.py`" in stamp and "2026-01-01 00:00 UTC" in stamp
    assert f"({tables.os.cpu_count()} cores)" in stamp and tables.cpu_model() in stamp
    assert re.search(r"commit `[0-9a-f]{4,}(\+dirty)?`|commit `unknown`", stamp)


@pytest.mark.parametrize("page", sorted((ROOT / "docs" / "performance").glob("*.md")))
def test_generated_tables_are_stamped(page):
    if page.name == "index.md":
        return
    text = page.read_text(encoding="utf-8")
    if "not generated yet" in text:  # a page that says so must say how to generate it
        assert "python benches/tables.py" in text or "--markdown" in text
        return
    assert "|---|" in text
    assert re.search(r"by\s+`python benches/[a-z_]+\.py[^`]*`", text), f"{page.name} names the command that made it"
