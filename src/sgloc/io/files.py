"""Opening user files safely: only regular files (a FIFO, device or folder is refused before it
is opened, so nothing blocks), and never more than a size bound into memory."""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

from sgloc.errors import GraphFileError, SglocError

#: Largest graph file read (bytes). A million objects in ASCII PCD is about 60 MB.
MAX_GRAPH_FILE_BYTES = 512 * 2**20
#: Largest numeric text file (poses, calibration, detections) read (bytes).
MAX_TEXT_FILE_BYTES = 256 * 2**20


def check_regular_file(
    path: str | Path, what: str, error: type[SglocError] = GraphFileError
) -> Path:
    """Return `path` if it names an existing regular file (symlinks followed); raise `error`
    naming the path and what was expected otherwise."""
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise error(f"{path}: no such file; give the path of a {what}.") from None
    except OSError as e:
        raise error(f"{path}: cannot access ({e.strerror}); give a readable {what}.") from None
    if stat.S_ISDIR(mode):
        raise error(f"{path}: is a folder; give a {what}.")
    if not stat.S_ISREG(mode):
        raise error(f"{path}: is not a regular file (a pipe or device); give a {what}.")
    return path


def read_regular_file(
    path: str | Path,
    what: str,
    max_bytes: int = MAX_GRAPH_FILE_BYTES,
    error: type[SglocError] = GraphFileError,
) -> bytes:
    """The bytes of a regular file of at most `max_bytes`; `error` (naming the file) otherwise."""
    path = check_regular_file(path, what, error)
    try:
        with open(path, "rb") as f:
            data = f.read(max_bytes + 1)
    except OSError as e:
        raise error(f"{path}: cannot read ({e.strerror}); give a readable {what}.") from None
    if len(data) > max_bytes:
        raise error(
            f"{path}: larger than {max_bytes // 2**20} MiB, the limit for a {what}; split the map "
            "or thin it out."
        )
    return data


@contextlib.contextmanager
def staged_folder(out: str | Path) -> Iterator[Path]:
    """Write a results folder atomically: yields an empty sibling folder to write into (holding
    a copy of `out`'s files when `out` exists), which replaces `out` by a rename once the block
    ends without error. On an error nothing of it stays and `out` is as before; an OSError
    becomes an SglocError naming the file (a full disk, a path too long)."""
    out = Path(out)
    stage: Path | None = None
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        stage = Path(tempfile.mkdtemp(prefix=f".{out.name[:100]}.partial-", dir=out.parent))
        if out.is_dir():
            shutil.copytree(out, stage, dirs_exist_ok=True)
        elif out.exists():
            raise SglocError(f"{out}: exists and is not a folder; give a results folder path.")
        yield stage
        _replace_folder(stage, out)
        stage = None
    except OSError as e:
        raise SglocError(_write_error(e, stage, out)) from None
    finally:
        if stage is not None:
            shutil.rmtree(stage, ignore_errors=True)


def _replace_folder(stage: Path, out: Path) -> None:
    """Rename `stage` to `out`; an existing `out` is moved aside first and removed after."""
    if not out.exists():
        os.rename(stage, out)
        return
    old = Path(tempfile.mkdtemp(prefix=f".{out.name[:100]}.old-", dir=out.parent))
    os.rename(out, old / out.name)
    os.rename(stage, out)
    shutil.rmtree(old, ignore_errors=True)


def _write_error(e: OSError, stage: Path | None, out: Path) -> str:
    """The message for a failed write: the file named by its final path, what to do."""
    if stage is None:  # the staging folder itself could not be made
        return f"{out}: cannot write ({e.strerror or e}); " + _hint(e)
    name = Path(e.filename) if e.filename else None
    if name is None and stage is not None and stage.is_dir():  # a write error names no file:
        files = [p for p in stage.rglob("*") if p.is_file()]  # the newest is the one written
        name = max(files, key=lambda p: p.stat().st_mtime_ns, default=None)
    if name is not None and name.is_relative_to(stage):
        name = out / name.relative_to(stage)
    where = name or out
    return f"{where}: cannot write ({e.strerror or e}); nothing was written to {out}; " + _hint(e)


def _hint(e: OSError) -> str:
    return {
        errno.ENOSPC: "free some disk space.",
        errno.ENAMETOOLONG: "choose a shorter results path.",
        errno.EACCES: "choose a folder you may write to.",
        errno.EROFS: "choose a writable folder.",
    }.get(e.errno, "check the results path.")


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write `text` to `path` through a temporary sibling file and a rename: the file holds
    the whole text or is as before; an OSError becomes an SglocError naming `path`."""
    path = Path(path)
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name[:100]}.", suffix=".tmp", dir=path.parent)
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
        tmp = None
    except OSError as e:
        raise SglocError(f"{path}: cannot write ({e.strerror or e}); " + _hint(e)) from None
    finally:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
    return path


@contextlib.contextmanager
def naming(path: str | Path) -> Iterator[None]:
    """An OSError in the block names `path` when it names no file (a write to a full disk)."""
    try:
        yield
    except OSError as e:
        if not e.filename:
            e.filename = str(path)
        raise
