"""Opening user files safely: only regular files (a FIFO, device or folder is refused before it
is opened, so nothing blocks), and never more than a size bound into memory."""

from __future__ import annotations

import os
import stat
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
