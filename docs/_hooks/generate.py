"""mkdocs hooks: pages generated at build time, never hand-copied.

- `cli.md`: the marker `<!-- generated: cli -->` becomes the `--help` of `jaxworm` and of
  each of its commands, from the argparse parser the command line itself uses.
- `changelog.md`: the marker `<!-- generated: changelog -->` becomes `CHANGELOG.md`.
- `benchmarks.md`: the marker `<!-- generated: benchmarks -->` becomes the committed
  results under `benchmarks/results/` (searched recursively): the index `README.md` if
  there is one, then every result in path order, its `.md` table, a summary of its `.json`
  (machine, date, command, where the file says them) and its `.png` figures. The `.json`
  and `.png` files are published beside the page.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import re
from pathlib import Path

from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "benchmarks" / "results"
#: Where the results' JSON and PNG files are published in the site.
PUBLISHED = "benchmarks-results"
CLI_MARKER = "<!-- generated: cli -->"
BENCH_MARKER = "<!-- generated: benchmarks -->"
CHANGELOG_MARKER = "<!-- generated: changelog -->"


# --- units in docstrings ----------------------------------------------------------------

#: Units as the docstrings write them, in brackets after an interval or a name
#: ("over [0, t1] [m/s]"). Markdown reads `[0, t1] [m/s]` as a reference link and autorefs
#: then reports a cross-reference it cannot find; for these targets that is no error.
UNITS = {"s", "m", "m/s", "rad", "rad/s", "N", "J", "J/m", "kg", "Pa", "Pa·√m", "Pa√m", "-"}


class _UnitReferences(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        m = re.search(r"Could not find cross-reference target '([^']*)'", record.getMessage())
        return not (m and m.group(1) in UNITS)


def on_config(config):
    # On mkdocs' handlers (among them the one that counts warnings for --strict), since
    # a logger's own filters do not see its children's records.
    for handler in logging.getLogger("mkdocs").handlers:
        if not any(isinstance(f, _UnitReferences) for f in handler.filters):
            handler.addFilter(_UnitReferences())
    return config


# --- CLI reference ---------------------------------------------------------------------


def _parser() -> argparse.ArgumentParser:
    from jaxworm.cli import build_parser

    return build_parser()


def _commands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def cli_reference() -> str:
    os.environ["COLUMNS"] = "100"  # argparse wraps help to the terminal's width
    parser = _parser()
    parts = ["## jaxworm", "", "```text", parser.format_help().rstrip(), "```", ""]
    for name, command in _commands(parser).items():
        parts += [f"## jaxworm {name}", "", "```text", command.format_help().rstrip(), "```", ""]
    return "\n".join(parts)


# --- benchmark results -----------------------------------------------------------------


SUFFIXES = (".md", ".json", ".png", ".npz")


def _stem(rel: Path) -> Path:
    """`rel` without its file type (only a known one: `x_lr_0.25` keeps its `.25`)."""
    return rel.with_suffix("") if rel.suffix in SUFFIXES else rel


def _anchor(rel: Path) -> str:
    return "result-" + re.sub(r"[^a-z0-9]+", "-", str(_stem(rel)).lower()).strip("-")


def _results() -> dict[Path, list[Path]]:
    """Result files by their path without suffix, relative to RESULTS, in path order."""
    groups: dict[Path, list[Path]] = {}
    if not RESULTS.is_dir():
        return groups
    for path in sorted(RESULTS.rglob("*")):
        rel = path.relative_to(RESULTS)
        if path.suffix in (".md", ".json", ".png") and rel != Path("README.md"):
            groups.setdefault(_stem(rel), []).append(rel)
    return dict(sorted(groups.items(), key=lambda kv: (kv[0].parent.as_posix(), kv[0].name)))


def _demote(text: str, levels: int) -> str:
    """Headings `#` → `#` × (1 + levels), outside code fences."""
    out, fenced = [], False
    for line in text.splitlines():
        if line.startswith("```"):
            fenced = not fenced
        if not fenced and re.match(r"#{1,6} ", line):
            line = "#" * levels + line
        out.append(line)
    return "\n".join(out)


def _relink(text: str, base: Path, groups: dict[Path, list[Path]]) -> str:
    """Links to result files become links into this page or to the published files;
    other relative links become code (they point outside the site)."""

    def sub(m: re.Match) -> str:
        bang, label, target = m.group(1), m.group(2), m.group(3)
        if re.match(r"[a-z]+:|#", target):
            return m.group(0)
        rel = Path(os.path.normpath(base / target.split("#")[0]))
        if rel != Path(".") and (RESULTS / rel).is_dir():
            return f"[{label}](#{_anchor(rel / 'folder')})"
        if _stem(rel) in groups and rel.suffix in (".md", ""):
            return f"[{label}](#{_anchor(rel)})"
        if rel.suffix in (".json", ".png") and (RESULTS / rel).is_file():
            return f"{bang}[{label}]({PUBLISHED}/{rel.as_posix()})"
        return f"{label} (`benchmarks/results/{rel.as_posix()}`)"

    return re.sub(r"(!?)\[([^\]]*)\]\(([^)\s]+)\)", sub, text)


#: What a result's JSON says about its run, in this order: top-level keys, then the keys
#: of its `machine` object.
RUN_KEYS = ("command", "argv", "date", "scene", "t1", "preset", "reference")
MACHINE_KEYS = ("cpu", "processor", "cpus", "device", "jax", "jaxworm", "git_commit", "date")


def _json_summary(path: Path) -> str:
    """The run's context as its JSON file states it (`RUN_KEYS`, `MACHINE_KEYS`)."""
    try:
        data = json.loads(path.read_text())
    except ValueError as e:
        return f"not readable as JSON: {e}"
    if not isinstance(data, dict):
        return ""
    items = {}
    for key in RUN_KEYS:
        value = data.get(key)
        if isinstance(value, list) and all(isinstance(v, str) for v in value):
            value = " ".join(value)
        if isinstance(value, (str, int, float)) and value != "":
            items[key] = value
    machine = data.get("machine")
    if isinstance(machine, dict):
        for key in MACHINE_KEYS:
            value = machine.get(key)
            if isinstance(value, (str, int, float)) and value != "" and key not in items:
                items[key] = value
    return "; ".join(f"{k} {v}" for k, v in items.items())


def benchmark_results(groups: dict[Path, list[Path]]) -> str:
    if not groups and not (RESULTS / "README.md").is_file():
        return "No results are committed under `benchmarks/results/`."
    parts = []
    index = RESULTS / "README.md"
    if index.is_file():
        parts += [_relink(_demote(index.read_text(), 1), Path("."), groups), ""]
    folder = None
    for stem, files in groups.items():
        if stem.parent != folder and stem.parent != Path("."):
            parts += [f"## `{stem.parent.as_posix()}/` {{#{_anchor(stem.parent / 'folder')}}}", ""]
        folder = stem.parent
        level = "###" if stem.parent != Path(".") else "##"
        parts += [f"{level} `{stem.as_posix()}` {{#{_anchor(stem)}}}", ""]
        for rel in files:
            if rel.suffix == ".md":
                text = _demote((RESULTS / rel).read_text(), len(level))
                parts += [_relink(text, rel.parent, groups), ""]
        for rel in files:
            if rel.suffix == ".json":
                summary = _json_summary(RESULTS / rel)
                link = f"[`{rel.name}`]({PUBLISHED}/{rel.as_posix()})"
                parts += [f"Data: {link}" + (f" ({summary})" if summary else "") + ".", ""]
            elif rel.suffix == ".png":
                parts += [f"![{rel.as_posix()}]({PUBLISHED}/{rel.as_posix()})", ""]
    return "\n".join(parts)


# --- mkdocs events ---------------------------------------------------------------------


def on_files(files, config):
    for rel in [r for group in _results().values() for r in group if r.suffix != ".md"]:
        files.append(
            File.generated(config, f"{PUBLISHED}/{rel.as_posix()}", abs_src_path=str(RESULTS / rel))
        )
    return files


def on_page_markdown(markdown, page, config, files):
    if CLI_MARKER in markdown:
        markdown = markdown.replace(CLI_MARKER, cli_reference())
    if CHANGELOG_MARKER in markdown:
        changelog = (ROOT / "CHANGELOG.md").read_text()
        markdown = markdown.replace(CHANGELOG_MARKER, _demote(changelog, 0))
    if BENCH_MARKER in markdown:
        markdown = markdown.replace(BENCH_MARKER, benchmark_results(_results()))
    return markdown
