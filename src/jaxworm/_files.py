"""Result files: the one format of sweeps, optimisation and training histories.

A result file is an uncompressed `.npz` archive (a zip of `.npy` members) written only
by jaxworm:

- `header`: a JSON object; its `format` names the kind (`FORMATS`) and `integrity`
  says that the member `checksum` holds the SHA-256 of every other member (name, dtype,
  shape and bytes), so a damaged file (a flipped byte, a truncated copy) is detected
  instead of read;
- the arrays of the kind (see `_sweep`, `_history` and `_train`).

A header starts with its kind's `format` and the package version (`header`), and a run
that would write over a file first checks that the file is a previous run of the same
computation (`previous`), which it then resumes or replaces.

Files are written atomically (a temporary file in the same folder, then `os.replace`),
with fixed zip timestamps, so the same results give the same bytes. Loading never
unpickles (`allow_pickle=False`) and every problem with a file is a `ResultFileError`
that names the file and what is wrong.

An output is claimed before any computation (`claim`): its folder must exist and be
writable, the path must not be a folder, its symbolic links are followed (two names of
one file are one output, and a link keeps naming its file), and an advisory lock
(`flock` on `<file>.lock`, beside the file itself, released by the kernel when the
process dies, so a killed run leaves no stale lock) refuses a second writer at once;
the temporary file of a writer killed while saving is removed by the next one. Files
written before the checksum existed (`integrity` absent) are still read.
"""

from __future__ import annotations

import contextlib
import glob
import hashlib
import json
import os
import secrets
import warnings
import zipfile
from pathlib import Path

import numpy as np

__all__ = [
    "ResultFileError",
    "FORMATS",
    "header",
    "plain",
    "differences",
    "DIGESTS",
    "previous",
    "save",
    "load",
    "claim",
    "check_output_path",
    "resolved",
    "digest",
]

#: The `format` of each kind of result file, and how it is read.
FORMATS = {
    "sweep": "jaxworm-sweep/1",
    "optimise": "jaxworm-optimise/1",
    "train": "jaxworm-train/1",
}
_DESCRIBED = {
    "sweep": "a jaxworm sweep file",
    "optimise": "a jaxworm optimisation history",
    "train": "a jaxworm training history",
}
_READER = {
    "sweep": "jaxworm.load_sweep",
    "optimise": "jaxworm.load_optimisation",
    "train": "jaxworm.load_training",
}
_INTEGRITY = "sha256 of the other members in member 'checksum'"
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)
_ZIP_MAGIC = b"PK\x03\x04"

#: How to go on when a file may not be overwritten (API and CLI spellings).
KEEP_REMEDY = (
    "jaxworm will not overwrite it: give another output path, delete it, or "
    "pass overwrite=True (CLI: --overwrite) to replace it"
)


class ResultFileError(ValueError):
    """A result file jaxworm cannot read or may not write: damaged, not a jaxworm file,
    the other kind of file, another run's, or being written by another process.

    `path` is the file as given, `problem` what is wrong with it, `remedy` (or None)
    what to do; the message says all three in one line.
    """

    def __init__(self, path, problem: str, remedy: str | None = None):
        self.path, self.problem, self.remedy = str(path), problem, remedy
        super().__init__(f"{self.path!r} {problem}" + (f"; {remedy}" if remedy else ""))


# --- headers -----------------------------------------------------------------------------


def header(kind: str, **fields) -> dict:
    """The header of a result file of `kind` (`FORMATS`): its format, the package
    version, then `fields` in order."""
    # Imported here: the rest of this module needs only NumPy and loads on its own.
    from ._version import __version__

    return {"format": FORMATS[kind], "version": __version__, **fields}


def plain(values: dict) -> dict:
    """`values` for a JSON header: ints and strings as they are, numbers and arrays as
    Python floats and (nested) lists, soil profiles (anything with `describe()`) as their
    dicts; None values left out. (No import of the package: this module loads alone.)"""
    return {
        k: (
            v
            if isinstance(v, (int, str))
            else v.describe()
            if callable(getattr(v, "describe", None))
            else np.asarray(v).tolist()
        )
        for k, v in values.items()
        if v is not None
    }


#: Digests a header carries beside readable fields that show part of what they cover
#: (`jaxworm._fingerprint`): the scene beside its flat parameters and model options, a
#: callable beside its name.
DIGESTS = {
    "base_scene": ("base_parameters", "model_options"),
    "objective_sha256": ("objective",),
    "apply_sha256": ("apply",),
}


def differences(old: dict, new: dict, keys) -> list[str]:
    """The `keys` in which two headers differ (compared as JSON). A digest of `DIGESTS`
    is named only when none of its readable fields differs (which says more)."""
    diff = [
        k
        for k in keys
        if json.dumps(old.get(k), sort_keys=True) != json.dumps(new.get(k), sort_keys=True)
    ]
    return [k for k in diff if not set(DIGESTS.get(k, ())) & set(diff)]


def previous(path: Path | None, overwrite: bool, load, differ, what: str):
    """The result already at `path` that a run may resume or replace, or None (no path,
    no file, or `overwrite`).

    `load(path)` reads it (its `ResultFileError` is raised again with `KEEP_REMEDY`);
    `differ(old)` lists what makes it another run's, in which case a `ResultFileError`
    says that the file holds `what` and what differs."""
    if path is None or overwrite or not path.exists():
        return None
    try:
        old = load(path)
    except ResultFileError as e:
        raise ResultFileError(path, e.problem, KEEP_REMEDY) from None
    diff = differ(old)
    if diff:
        raise ResultFileError(path, f"holds {what} ({', '.join(diff)} differ)", KEEP_REMEDY)
    return old


# --- writing -----------------------------------------------------------------------------


def digest(members: dict[str, np.ndarray]) -> str:
    """SHA-256 (hex) of named arrays: each name, dtype, shape and bytes, in name order."""
    h = hashlib.sha256()
    for name in sorted(members):
        a = np.ascontiguousarray(members[name])
        h.update(json.dumps([name, a.dtype.str, list(a.shape)]).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def save(path, header: dict, arrays: dict[str, np.ndarray]) -> None:
    """Write a result file atomically: an interrupted save leaves the old file whole and
    no temporary file behind. OSError messages name `path`, not the temporary file."""
    path = Path(path)
    members = {
        "header": np.asarray(json.dumps({**header, "integrity": _INTEGRITY})),
        **{k: np.asarray(v) for k, v in arrays.items()},
    }
    members["checksum"] = np.asarray(digest(members))
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        with os.fdopen(fd, "wb") as fh:
            with zipfile.ZipFile(fh, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
                for name, arr in members.items():
                    info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_TIME)
                    with zf.open(info, "w", force_zip64=True) as m:
                        np.lib.format.write_array(m, arr, allow_pickle=False)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as e:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise OSError(e.errno, f"cannot save {str(path)!r}: {e.strerror or e}") from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


# --- reading -----------------------------------------------------------------------------


def _reason(e: BaseException) -> str:
    text = " ".join(str(e).split()) or type(e).__name__
    if isinstance(e, zipfile.BadZipFile) and text == "File is not a zip file":
        return "truncated: the zip directory at its end is missing"
    if "pickle" in text:  # never pass on numpy's advice to unpickle an untrusted file
        return "it holds pickled Python objects, which jaxworm never loads"
    return text


def load(path, kind: str) -> tuple[dict, dict[str, np.ndarray]]:
    """(header, arrays) of the result file `path` of `kind` (`FORMATS`), checked: the
    archive, every member, the header's format and the checksum. Raises
    `ResultFileError` for anything but such a file (FileNotFoundError if it is absent)."""
    path = Path(path)
    if path.is_dir():
        raise ResultFileError(path, f"is a folder, not {_DESCRIBED[kind]}")
    size = path.stat().st_size
    if size == 0:
        raise ResultFileError(path, f"is empty (0 bytes): not {_DESCRIBED[kind]}")
    with open(path, "rb") as fh:
        magic = fh.read(4)
    if magic != _ZIP_MAGIC:
        raise ResultFileError(path, f"is not {_DESCRIBED[kind]} (not an .npz archive)")
    members: dict[str, np.ndarray] = {}
    try:
        with zipfile.ZipFile(path) as zf:
            for info in zf.infolist():
                if info.file_size > size or not info.filename.endswith(".npy"):
                    raise ValueError(f"member {info.filename!r} is not one jaxworm writes")
                with zf.open(info) as m:
                    members[info.filename[:-4]] = np.lib.format.read_array(m, allow_pickle=False)
                    if m.read(1):
                        raise ValueError(f"member {info.filename!r} has trailing bytes")
        checksum = members.pop("checksum", None)
        expected = digest(members) if checksum is not None else None
        header = json.loads(str(members.pop("header")))
        if not isinstance(header, dict):
            raise ValueError("its header is not a JSON object")
    except KeyError:
        raise damaged(path, "it has no header") from None
    except Exception as e:  # noqa: BLE001 - BadZipFile, EOFError, struct.error...: all damage
        raise damaged(path, _reason(e)) from None
    if checksum is not None or "integrity" in header:
        if checksum is None or header.get("integrity") != _INTEGRITY:
            raise damaged(path, "its checksum is missing")
        if str(checksum) != expected:
            raise damaged(path, "its checksum does not match")
    fmt = header.get("format")
    if fmt != FORMATS[kind]:
        other = [k for k, f in FORMATS.items() if f == fmt and k != kind]
        if other:
            raise ResultFileError(
                path,
                f"is {_DESCRIBED[other[0]]}, not {_DESCRIBED[kind]}",
                f"read it with {_READER[other[0]]}",
            )
        raise ResultFileError(
            path, f"is not {_DESCRIBED[kind]} (format {fmt!r}, need {FORMATS[kind]!r})"
        )
    return header, members


def damaged(path, what: str) -> ResultFileError:
    """The error for a file whose members do not fit its kind (shapes, keys)."""
    return ResultFileError(
        path, f"is damaged ({what})", "it cannot be read: delete it, or write it again"
    )


# --- claiming an output ------------------------------------------------------------------


def check_output_path(path) -> Path:
    """`path` as a Path if a result file may be written there: not a folder, not some
    other kind of file, in a folder that exists and is writable; else ResultFileError.
    Cheap: call it before any computation."""
    path = Path(path)
    folder = path.parent
    if path.is_dir():
        raise ResultFileError(
            path, "is a folder", f"give a file path such as {str(path / 'results.npz')!r}"
        )
    if path.exists() and not path.is_file():
        raise ResultFileError(path, "exists and is not a regular file", "give another path")
    if folder.exists() and not folder.is_dir():
        raise ResultFileError(
            path,
            f"cannot be written: {str(folder)!r}, where its folder should be, is a file",
            "give another path",
        )
    if not folder.is_dir():
        raise ResultFileError(
            path,
            f"cannot be written: its folder {str(folder)!r} does not exist",
            "create it first, or give another path",
        )
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ResultFileError(
            path,
            f"cannot be written: no permission to write in its folder {str(folder)!r}",
            "give another path",
        )
    return path


class _Lock:
    """An exclusive advisory lock on `<path>.lock` (`flock`), or a ResultFileError at once.

    The lock file holds the holder's pid, for the message; the kernel drops the lock
    when its holder dies, so a killed run leaves at most a stale, unlocked file, which
    the next run takes over. On a filesystem that refuses locks the file is written
    unlocked, with a warning; without `fcntl` (Windows) nothing is locked.
    """

    def __init__(self, path: Path):
        self.path = path
        self.lock_path = path.with_name(path.name + ".lock")
        self.fd: int | None = None

    def acquire(self) -> None:
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not on POSIX
            return
        while True:
            try:
                fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o666)
            except OSError as e:
                raise ResultFileError(
                    self.path,
                    f"cannot be written: its lock file "
                    f"{str(self.lock_path)!r} cannot be created "
                    f"({e.strerror or e})",
                    "give a path in a writable folder",
                ) from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = ""
                with contextlib.suppress(OSError):
                    holder = os.read(fd, 32).decode(errors="replace").strip()
                os.close(fd)
                who = f"pid {holder}" if holder.isdigit() else "pid unknown"
                raise ResultFileError(
                    self.path,
                    f"is being written by another jaxworm process "
                    f"({who}; lock {str(self.lock_path)!r})",
                    "wait for it to finish, or give another output path",
                ) from None
            except OSError as e:  # a filesystem without locks (ENOLCK, EOPNOTSUPP)
                warnings.warn(
                    f"{str(self.path)!r} is written unlocked: its folder's filesystem "
                    f"refuses locks ({e.strerror or e}), so another jaxworm process "
                    "writing it at the same time would not be refused",
                    stacklevel=4,
                )
                break
            # The holder may have removed the file (releasing) between our open and flock;
            # then we hold a lock on a file nobody else will see: open it again.
            try:
                current = os.stat(self.lock_path)
            except FileNotFoundError:
                current = None
            if current is not None and os.path.samestat(os.fstat(fd), current):
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self.fd = fd

    def release(self) -> None:
        if self.fd is None:
            return
        with contextlib.suppress(OSError):
            os.unlink(self.lock_path)  # before closing: nobody can lock this file after us
        os.close(self.fd)
        self.fd = None


def resolved(path) -> Path:
    """`path` as given, or, when it is a symbolic link, the file it names (links followed
    to the end by `os.path.realpath`; the file need not exist yet): the name beside which
    every writer of that file takes its lock. (Links among the folders need no following:
    the lock file sits in the same folder whatever its name.)"""
    return Path(os.path.realpath(path)) if os.path.islink(path) else Path(path)


@contextlib.contextmanager
def claim(path):
    """Check `path` as an output (`check_output_path`) and hold its lock meanwhile; yields
    the file to write, `path` with its links followed (`resolved`), so that two names of
    one file take one lock and a write through a link replaces the file it names, not
    the link. With `path=None` yields None and does nothing."""
    if path is None:
        yield None
        return
    path = check_output_path(resolved(check_output_path(path)))
    lock = _Lock(path)
    lock.acquire()
    # Temporary files of this output can only be left by a writer that was killed while
    # saving (only the lock's holder writes them): remove them.
    for stale in path.parent.glob(f".{glob.escape(path.name)}.{'[0-9a-f]' * 8}.tmp"):
        with contextlib.suppress(OSError):
            stale.unlink()
    try:
        yield path
    finally:
        lock.release()
