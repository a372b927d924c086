"""The benchmarks' structure, read from the source (no JAX, no run): their imports form
no cycle, the modules tests share with them import no sibling, nothing edits `sys.path`,
and they (and the docs' own code) import public jaxworm names only. Results are stamped
with the code that made them, marked `-dirty` when that code was not committed.
"""

from __future__ import annotations

import ast
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
BENCH = ROOT / "benchmarks"
MODULES = {p.stem: p for p in BENCH.glob("*.py") if p.stem != "__init__"}
#: Imported by tests as `benchmarks.<name>`, so they must import no sibling by name.
SHARED = ("scenes", "reference_model", "fuzz_cases", "_results")


def _imports(path: Path) -> set[str]:
    """Sibling modules `path` imports, anywhere in it (function bodies included)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        for name in names:
            name = name.removeprefix("benchmarks.")
            if name.split(".")[0] in MODULES:
                found.add(name.split(".")[0])
    return found


GRAPH = {name: _imports(path) for name, path in MODULES.items()}


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle of `graph`, or None."""
    state: dict[str, int] = {}  # 1: on the stack, 2: done
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if state.get(m) == 1:
                return stack[stack.index(m) :] + [m]
            if m not in state and (found := visit(m)):
                return found
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state and (found := visit(n)):
            return found
    return None


def test_the_cycle_finder_finds_a_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_benchmark_imports_form_no_cycle():
    assert "_bench" in GRAPH and GRAPH["work_precision"] >= {"_bench", "study"}
    assert _cycle(GRAPH) is None


@pytest.mark.parametrize("name", SHARED)
def test_modules_shared_with_tests_import_no_sibling(name):
    assert GRAPH[name] == set()


@pytest.mark.parametrize(
    "path",
    sorted(BENCH.glob("*.py")) + sorted((ROOT / "tests").glob("*.py")),
    ids=lambda p: f"{p.parent.name}/{p.name}",
)
def test_no_sys_path_edits(path):
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if (
            isinstance(node, ast.Attribute)
            and node.attr == "path"
            and isinstance(node.value, ast.Name)
            and node.value.id == "sys"
        ):
            raise AssertionError(f"{path.name}:{node.lineno} uses sys.path")


def _private_imports(source: str) -> list[int]:
    """Lines of `source` that import a private jaxworm name (`jaxworm._x`, or `_x` from
    `jaxworm` or one of its modules)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            private = node.module.startswith("jaxworm._") or (
                node.module.split(".")[0] == "jaxworm"
                and any(a.name.startswith("_") for a in node.names)
            )
        elif isinstance(node, ast.Import):
            private = any(a.name.startswith("jaxworm._") for a in node.names)
        else:
            continue
        if private:
            found.append(node.lineno)
    return found


def test_the_private_import_finder_finds_them():
    assert _private_imports("from jaxworm._cli import main\nimport jaxworm._sweep") == [1, 2]
    assert _private_imports("def f():\n    from jaxworm import _sweep") == [2]
    assert _private_imports("import jaxworm as jw\nfrom jaxworm.cli import main") == []


@pytest.mark.parametrize(
    "path",
    sorted(BENCH.glob("*.py")) + sorted((ROOT / "docs").rglob("*.py")),
    ids=lambda p: f"{p.parent.name}/{p.name}",
)
def test_benchmarks_and_docs_code_import_public_names_only(path):
    lines = _private_imports(path.read_text(encoding="utf-8"))
    assert lines == [], f"{path.name}: private jaxworm imports on lines {lines}"


def test_code_version_marks_uncommitted_code_but_not_results(tmp_path):
    from benchmarks._results import code_version

    def git(*args):
        run = subprocess.run(["git", *args], cwd=tmp_path, check=True, capture_output=True)
        return run.stdout.decode().strip()

    for f in ("src/m.py", "benchmarks/b.py", "benchmarks/results/b/r.json", "pyproject.toml"):
        (tmp_path / f).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / f).write_text("1\n")
    git("init", "-q")
    git("add", ".")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "c")
    head = git("rev-parse", "--short", "HEAD")
    assert code_version(tmp_path) == head
    (tmp_path / "benchmarks/results/b/r.json").write_text("2\n")  # a re-run's own output
    assert code_version(tmp_path) == head
    for f in ("src/m.py", "benchmarks/b.py", "pyproject.toml", "src/new.py"):
        original = (tmp_path / f).read_text() if (tmp_path / f).exists() else None
        (tmp_path / f).write_text("2\n")
        assert code_version(tmp_path) == head + "-dirty", f
        assert code_version(tmp_path / "benchmarks") == head + "-dirty", f  # from inside
        if original is None:
            (tmp_path / f).unlink()
        else:
            (tmp_path / f).write_text(original)
    assert code_version(tmp_path) == head
    assert code_version(Path("/")) == ""  # not a checkout
