"""Outputs named on the command line, checked before anything is computed: single files
(a figure, an animation), whose folder must exist; folders of several outputs, created
when missing; and files that two options must not share."""

from __future__ import annotations

import os
from pathlib import Path

from .values import UsageError


def figure_file(option: str, out: Path, default_name: str) -> Path:
    """The figure file `out` names (`.png` added when it has no suffix), checked before
    anything is computed: a format matplotlib writes, and an `output_file`."""
    # matplotlib takes ~0.5 s to import: only the commands that draw pay for it.
    from matplotlib.backend_bases import FigureCanvasBase

    if out.is_dir():
        raise UsageError(
            f"{option} {str(out)!r} is a folder: give a file such as {str(out / default_name)!r}"
        )
    if not out.suffix:
        out = out.with_suffix(".png")
    formats = FigureCanvasBase.get_supported_filetypes()
    if out.suffix.lower().lstrip(".") not in formats:
        raise UsageError(
            f"{option} {str(out)!r}: unknown figure format {out.suffix!r}; "
            f"need one of {', '.join('.' + f for f in sorted(formats))}"
        )
    return output_file(option, out, default_name)


def output_file(option: str, out: Path, default_name: str) -> Path:
    """`out`, a file `option` names, checked before anything is computed: not a folder,
    in a folder that exists and is writable (none is created, as for every single-file
    output)."""
    if out.is_dir():
        raise UsageError(
            f"{option} {str(out)!r} is a folder: give a file such as {str(out / default_name)!r}"
        )
    folder = out.parent
    if folder.exists() and not folder.is_dir():
        raise UsageError(f"{option} {str(out)!r}: {str(folder)!r} is a file, not a folder")
    if not folder.is_dir():
        raise UsageError(
            f"{option} {str(out)!r}: folder {str(folder)!r} does not exist; create it first"
        )
    if not os.access(folder, os.W_OK | os.X_OK):
        raise UsageError(f"{option} {str(out)!r}: no permission to write in folder {str(folder)!r}")
    return writable(option, out)


def writable(option: str, out: Path) -> Path:
    """`out`; `UsageError` naming `option` when a file there cannot be written (read-only,
    immutable): found before anything is computed, not when the output is written.
    Opened for appending and closed at once, the file is left as it was."""
    if out.is_file():
        try:
            with open(out, "ab"):
                pass
        except OSError as e:
            raise UsageError(
                f"{option} {str(out)!r}: cannot write this file ({e.strerror or e}); "
                "give another file or make it writable"
            ) from None
    return out


def output_folder(option: str, folder: Path) -> Path:
    """The folder `option` names for several outputs, created (with its parents) when
    missing, before anything is computed; `UsageError` when it is a file or cannot be
    created or written."""
    if folder.exists() and not folder.is_dir():
        raise UsageError(
            f"{option} {str(folder)!r} is a file, not a folder: give a folder "
            "(created if missing) for its outputs"
        )
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UsageError(
            f"{option} {str(folder)!r}: cannot create the folder ({e.strerror or e})"
        ) from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise UsageError(f"{option} {str(folder)!r}: no permission to write in this folder")
    return folder


def file_in_folder(option: str, folder: Path, name: str) -> Path:
    """The output `name` in the folder `option` names (`output_folder`); `UsageError`
    when a folder is in its way."""
    path = folder / name
    if path.is_dir():
        raise UsageError(
            f"{option} {str(folder)!r}: {str(path)!r} is a folder, so {name} cannot be "
            "written there; remove it or give another folder"
        )
    return writable(option, path)


def figure_path(out: Path | None, fmt: str | None, stem: str) -> Path:
    """The .png or .pdf figure file from --out and --format (`stem`.png when neither is
    given); `UsageError` when they disagree."""
    if out is None:
        return Path(f"{stem}.{fmt or 'png'}")
    if out.is_dir():  # kept as it is: `figure_file` refuses it
        return out
    suffix = out.suffix.lower().lstrip(".")
    if not suffix:
        return out.with_suffix(f".{fmt or 'png'}")
    if suffix not in ("png", "pdf"):
        raise UsageError(f"--out {out}: the figure suffix must be .png or .pdf")
    if fmt is not None and suffix != fmt:
        raise UsageError(f"--out {out} does not match --format {fmt}")
    return out


def same_file(a: Path, b: Path) -> bool:
    """Whether `a` and `b` name one file: equal once resolved (links followed), or, both
    existing, the same inode (a hard link)."""
    if a.resolve() == b.resolve():
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def check_distinct(files: dict[str, Path | None]) -> None:
    """`UsageError` when two of `files` ({option: path}; None: not given) name one file:
    one would be written over the other."""
    given = [(option, path) for option, path in files.items() if path is not None]
    for i, (first, a) in enumerate(given):
        for second, b in given[i + 1 :]:
            if same_file(a, b):
                raise UsageError(
                    f"{first} {str(a)!r} and {second} {str(b)!r} name the same file: "
                    "one would be written over the other; give two different files"
                )
