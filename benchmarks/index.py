"""Write `benchmarks/results/README.md`: one row per committed result, by benchmark, with
the command that made it, the machine, the date and the load, and links to its files.

    python benchmarks/index.py

Built from the committed files alone (nothing is re-run). From each result's JSON: its
`run` record (`_results.write_json`: command, machine, cores, date, load, code), else the
`command`, `machine` and `date` entries older files carry; the command, where none is
recorded, is the one that writes that file name today (`--quick` for `_quick`, and the
option suffixes of the optimisation benchmarks); the date, where none is recorded, is
the file's last commit (`git log`).
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

from _results import RESULTS

HERE = Path(__file__).resolve().parent

#: File-name suffixes of the options (`_bench.gradient_tag`, the scripts' own), in the
#: order the scripts write them, and the flags they stand for.
SUFFIXES = [
    (r"_quick", lambda m: "--quick"),
    (r"_horizon_(t1|whole_periods)", lambda m: f"--horizon {m[1]}"),
    (r"_(sigmoid|sine)", lambda m: f"--box {m[1]}"),
    (r"_(rprop)", lambda m: "--optimiser rprop"),
    (r"_b1_([0-9.]+)", lambda m: f"--b1 {m[1]}"),
    (r"_lr_([0-9.]+)", lambda m: f"--lr {m[1]}"),
    (r"_constant", lambda m: "--no-decay"),
    (r"_t1_([0-9.]+)", lambda m: f"--t1 {m[1]}"),
    (r"_batched", lambda m: "--batched"),
    (r"_ramp_([0-9.]+)", lambda m: f"--sensitivity-ramp {m[1]}"),
    (r"_noise\d+", None),  # one history per noise level, not an option
]
#: Files that belong to another result of the same folder (stem -> the stem they join).
COMPANIONS = {
    "optimise_grid": "optimise_vs_grid",
    "optimise_history": "optimise_vs_grid",
    "optimise_paths": "optimise_vs_grid",
    "gradient_accuracy_reference": "gradient_accuracy",
}
#: Extra runs of a benchmark that are parts of its study (their own rows).
PARTS = {"presets", "run_info"}


def flags_of(suffix: str) -> tuple[list[str], str]:
    """The flags a file-name suffix stands for, and what is left of it unread."""
    flags = []
    for pattern, flag in SUFFIXES:
        m = re.match(pattern, suffix)
        if m:
            if flag is not None:
                flags.append(flag(m))
            suffix = suffix[m.end() :]
    return flags, suffix


def group(folder: Path) -> dict[str, dict]:
    """The runs of one benchmark folder: `{run key: {"stem", "suffix", "files"}}`."""
    bench = folder.name
    runs: dict[str, dict] = {}
    for f in sorted(p for p in folder.iterdir() if p.is_file()):
        stem = f.stem
        base = next(
            (
                b
                for b in sorted({bench, *COMPANIONS, *PARTS}, key=len, reverse=True)
                if stem == b or stem.startswith(b + "_")
            ),
            bench,
        )
        suffix = stem[len(base) :] if stem.startswith(base) else ""
        suffix = re.sub(r"_noise\d+$", "", suffix)
        owner = COMPANIONS.get(base, base)
        key = f"{owner}{suffix}"
        runs.setdefault(key, {"stem": owner, "suffix": suffix, "files": []})["files"].append(f)
    return runs


def _git_date(path: Path) -> str:
    try:
        out = subprocess.run(
            ["git", "log", "--follow", "-1", "--format=%cI", "--", str(path)],
            cwd=HERE,
            capture_output=True,
            text=True,
        ).stdout.strip()
    except OSError:
        out = ""
    return out


def describe(bench: str, run: dict) -> dict:
    """Command, machine, date and load of one run, from its JSON or its name."""
    main = next((f for f in run["files"] if f.name == f"{run['stem']}{run['suffix']}.json"), None)
    data = json.loads(main.read_text()) if main else {}
    rec = data.get("run", {}) if isinstance(data, dict) else {}
    m = data.get("machine", {}) if isinstance(data, dict) else {}
    m = m if isinstance(m, dict) else {"cpu": m}
    command = rec.get("command") or (data.get("command") if isinstance(data, dict) else None)
    source = "recorded"
    if not command:
        md = next((f for f in run["files"] if f.suffix == ".md"), None)
        found = re.search(r"Command: `([^`]+)`", md.read_text()) if md else None
        if found:
            command = found[1]
        else:
            flags, _ = flags_of(run["suffix"])
            command = " ".join([f"python benchmarks/{bench}.py", *flags])
            source = "from the file name"
    cpu = rec.get("machine") or m.get("cpu") or m.get("processor") or m.get("platform") or "—"
    cores = rec.get("cores") or m.get("cpus")
    date = (
        rec.get("date") or m.get("date") or (data.get("date") if isinstance(data, dict) else None)
    )
    date_source = "recorded"
    if not date:
        date, date_source = _git_date(run["files"][0]), "committed"
    load = rec.get("load") or m.get("load_average_at_start") or m.get("load_average_end")
    code = rec.get("code") or m.get("git_commit")
    return {
        "command": command,
        "command_source": source,
        "machine": f"{cpu}, {cores} cores" if cores else cpu,
        "date": f"{date[:16].replace('T', ' ')}"
        + ("" if date_source == "recorded" else " (committed)"),
        "load": "—" if not load else " / ".join(f"{x:.1f}" for x in load),
        "code": f"`{code}`" if code else "—",
    }


def index() -> str:
    lines = [
        "# Benchmark results",
        "",
        "Generated by `python benchmarks/index.py` from the committed files; do not edit.",
        "One folder per benchmark (`benchmarks/<benchmark>.py` writes "
        "`results/<benchmark>/`); `_quick` marks a `--quick` run; other suffixes name "
        "the options that differ from the script's defaults. Load: the 1-, 5- and "
        "15-minute load averages when the run started (or ended, where only that was "
        "recorded). A command marked * is not recorded in the file: it is the one that "
        "writes that file name today. Code: the commit the run was made at, `-dirty` "
        "where the library or the benchmark scripts differed from it (— where not "
        "recorded).",
        "",
        "| benchmark | files | command | machine | date (UTC) | load | code |",
        "|---|---|---|---|---|---|---|",
    ]
    for folder in sorted(p for p in RESULTS.iterdir() if p.is_dir()):
        for _key, run in sorted(group(folder).items()):
            d = describe(folder.name, run)
            files = ", ".join(f"[{f.name}]({folder.name}/{f.name})" for f in run["files"])
            star = "" if d["command_source"] == "recorded" else " *"
            lines.append(
                f"| {folder.name} | {files} | `{d['command']}`{star} | {d['machine']} "
                f"| {d['date']} | {d['load']} | {d['code']} |"
            )
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    import argparse

    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args(argv)
    text = index()
    (RESULTS / "README.md").write_text(text)
    print(f"wrote {RESULTS / 'README.md'} ({text.count(chr(10)) - 8} rows)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
