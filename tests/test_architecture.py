"""The library's modules import one way: no cycle among `jaxworm`'s modules (the
package's `__init__`, which re-exports them, and the command line, which sits on top
and imports the package, aside). Read from the sources' top-level imports; no JAX. And
what users read (README, docs, notebooks) names public modules only, the console script
among them."""

import ast
import json
import re
import tomllib
from pathlib import Path

import jaxworm

ROOT = Path(jaxworm.__file__).parent


def _modules() -> dict[str, Path]:
    out = {}
    for f in ROOT.rglob("*.py"):
        parts = f.relative_to(ROOT.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = f
    return out


def _graph() -> dict[str, set[str]]:
    mods = _modules()
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for m, f in mods.items():
        package = m if f.name == "__init__.py" else m.rsplit(".", 1)[0]
        for node in ast.parse(f.read_text()).body:
            if isinstance(node, ast.ImportFrom):
                if node.level:  # relative: up (level - 1) packages from this one
                    base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                for alias in node.names:
                    for cand in (f"{target}.{alias.name}", target):
                        if cand in mods and cand != m:
                            graph[m].add(cand)
                            break
            elif isinstance(node, ast.Import):
                graph[m] |= {a.name for a in node.names if a.name in mods and a.name != m}
    return graph


def _cycles(graph: dict[str, set[str]], skip: set[str]) -> list[list[str]]:
    found, state = [], {}

    def visit(u, stack):
        state[u] = "open"
        stack.append(u)
        for v in sorted(graph[u] - skip):
            if state.get(v) == "open":
                found.append(stack[stack.index(v) :] + [v])
            elif v not in state:
                visit(v, stack)
        stack.pop()
        state[u] = "done"

    for m in sorted(set(graph) - skip):
        if m not in state:
            visit(m, [])
    return found


def test_the_graph_is_read():
    g = _graph()
    assert "jaxworm._solve" in g["jaxworm._sweep"]
    assert "jaxworm._physics" in g["jaxworm._dynamics"]


def test_no_import_cycle_among_the_library_modules():
    assert _cycles(_graph(), skip={"jaxworm"}) == []


def test_the_cycle_check_finds_a_cycle():
    g = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}
    assert _cycles(g, skip=set()) == [["a", "b", "c", "a"]]


def test_only_the_command_line_imports_the_package():
    importers = sorted(m for m, deps in _graph().items() if "jaxworm" in deps)
    assert all(m.startswith("jaxworm._cli") for m in importers), importers


REPO = ROOT.parent.parent
#: A private jaxworm name in text: `jaxworm._x`, or `_x` imported from jaxworm or a module.
PRIVATE = re.compile(r"\bjaxworm\._\w|\bfrom\s+jaxworm(?:\.\w+)*\s+import\s+\(?\s*_\w")


def _user_text() -> dict[str, str]:
    """The README, the docs' pages and the notebooks' code cells, by path."""
    out = {"README.md": (REPO / "README.md").read_text(encoding="utf-8")}
    for page in sorted((REPO / "docs").rglob("*.md")):
        out[str(page.relative_to(REPO))] = page.read_text(encoding="utf-8")
    for nb in sorted((REPO / "notebooks").glob("*.ipynb")):
        cells = json.loads(nb.read_text(encoding="utf-8"))["cells"]
        code = ["".join(c["source"]) for c in cells if c["cell_type"] == "code"]
        out[str(nb.relative_to(REPO))] = "\n".join(code)
    return out


def test_the_private_name_pattern_finds_them():
    hits = ["import jaxworm._plot", "from jaxworm import _cli", "jaxworm._sweep.CHUNK_COST"]
    assert all(PRIVATE.search(t) for t in hits)
    assert not any(PRIVATE.search(t) for t in ("from jaxworm.cli import main", "jw.sweep"))


def test_readme_docs_and_notebooks_use_public_names_only():
    text = _user_text()
    assert "README.md" in text and any(p.endswith(".ipynb") for p in text)
    bad = {p: PRIVATE.findall(t) for p, t in text.items() if PRIVATE.search(t)}
    assert bad == {}


def test_the_console_script_is_the_public_cli_main():
    import jaxworm.cli
    from jaxworm import _cli

    scripts = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]
    module, name = scripts["jaxworm"].split(":")
    assert module == "jaxworm.cli" and not any(p.startswith("_") for p in module.split("."))
    assert getattr(jaxworm.cli, name) is _cli.main
