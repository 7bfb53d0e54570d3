"""Opening user files safely (only regular files: a FIFO, device or folder is refused before it
is opened, so nothing blocks; never more than a size bound into memory) and writing outputs
safely (the one writer of results folders and output files: atomic, after the umask, never over
anything sgloc did not write)."""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import shutil
import stat
import tempfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from sgloc.errors import GraphFileError, OutputPathError, SglocError
from sgloc.runtime import interrupts

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


# -- outputs: results folders and single files ----------------------------------------------------
# Every command writes through `staged_folder` or `staged_file`: the output is written beside its
# place under a hidden name carrying the writer's pid, then renamed into place, so it appears
# complete or not at all. An output only ever replaces what sgloc wrote: a results folder is
# marked by MANIFEST, which lists every entry sgloc wrote in it.

#: The file that marks a results folder as sgloc's; it lists what sgloc wrote in the folder.
MANIFEST = ".sgloc-results.json"
#: The manifest's schema name.
MANIFEST_SCHEMA = "sgloc.results-folder/1"
#: Hidden names of this writer beside an output: staging, set aside, lock (`.NAME.KIND-PID-x`).
_SIDE = re.compile(r"^\.(?P<name>.+)\.(?:partial|old|tmp)-(?P<pid>\d+)(?:-[^/]*)?$")


def check_output_path(
    out: str | Path, inputs: Sequence[str | Path | None] = (), option: str = "--out",
    folder: bool = True, ours: Callable[[Path], bool] | None = None,
) -> Path:
    """Return `out` if sgloc may write it: a results folder (`folder`) or a single file that does
    not exist, an empty folder, or an earlier output of sgloc (a folder holding only what its
    MANIFEST lists; a file `ours(path)` recognises). OutputPathError (naming `out`, what it
    holds and the fix) when it is the working folder or holds it, the home or root folder, an
    input or a folder holding one, a results folder inside an input folder, or anything else
    that exists."""
    out = Path(out)
    fix = f"give a new path for {option}, such as results/NAME"
    where = _real(out)
    if where == Path(where.anchor) or where == _home():
        raise OutputPathError(f"{out}: is the {'root' if where == Path(where.anchor) else 'home'}"
                              f" folder; sgloc never writes over it; {fix}.")
    if _real(Path.cwd()).is_relative_to(where):
        raise OutputPathError(f"{out}: is the working folder or holds it; sgloc never replaces "
                              f"a folder you work in; {fix}.")
    for given in (p for p in inputs if p is not None):
        src = _real(Path(given))
        if src == where or src.is_relative_to(where):
            what = "is the input" if src == where else "holds the input"
            raise OutputPathError(f"{out}: {what} {given}; sgloc never writes over its inputs; "
                                  f"{fix}.")
        if folder and where.is_relative_to(src) and os.path.isdir(src):
            raise OutputPathError(f"{out}: lies inside the input folder {given}, where it would "
                                  f"be read as input; give {option} a path outside it.")
    if os.path.islink(out):
        raise OutputPathError(f"{out}: is a symbolic link; give the path it points to or {fix}.")
    if folder:
        _replaceable_folder(out, option)
    elif _is(out, stat.S_ISDIR):
        raise OutputPathError(f"{out}: is a folder; {option} takes a file path.")
    elif _is(out, lambda mode: True) and ours is None:
        raise OutputPathError(f"{out}: exists; {option} writes a new file only, never over an "
                              f"existing one; give a new path or move the file away first.")
    elif _is(out, lambda mode: True) and not ours(out):
        raise OutputPathError(f"{out}: exists and was not written by sgloc; give a new path for "
                              f"{option} or move the file away first.")
    return out


def _is(path: Path, kind: Callable[[int], bool]) -> bool:
    """True if `path` exists and its mode is of `kind`; SglocError when it cannot be looked at."""
    try:
        return bool(kind(os.stat(path).st_mode))
    except FileNotFoundError:
        return False
    except OSError as e:
        raise SglocError(f"{path}: cannot write ({e.strerror or e}); {_hint(e)}") from None


def _home() -> Path | None:
    try:
        return _real(Path.home())
    except (RuntimeError, KeyError):  # no home folder known
        return None


def _real(path: Path) -> Path:
    """`path` absolute with every symbolic link resolved (`..` after a link as the OS does)."""
    return Path(os.path.realpath(path))


def _replaceable_folder(out: Path, option: str) -> str:
    """'absent', 'empty' or 'ours' (an earlier results folder); OutputPathError otherwise."""
    try:
        mode = os.stat(out).st_mode
    except FileNotFoundError:
        return "absent"
    except OSError as e:
        raise SglocError(f"{out}: cannot write ({e.strerror or e}); {_hint(e)}") from None
    if not stat.S_ISDIR(mode):
        raise OutputPathError(f"{out}: exists and is not a folder; give a results folder path "
                              f"for {option}.")
    try:
        entries = sorted(_entries(out))
    except OSError as e:
        raise OutputPathError(f"{out}: cannot list ({e.strerror}); {_hint(e)}") from None
    if not entries:
        return "empty"
    listed = _manifest(out)
    if listed is None:
        raise OutputPathError(f"{out}: holds files sgloc did not write (e.g. {entries[0]}); "
                              f"give a new or empty folder for {option}.")
    extra = [e for e in entries if e not in listed]
    if extra:
        raise OutputPathError(f"{out}: an earlier results folder that now also holds {extra[0]}, "
                              f"which sgloc did not write; move it away or give a new folder "
                              f"for {option}.")
    return "ours"


def _entries(folder: Path) -> Iterator[str]:
    """Every entry under `folder` but the manifest, relative, folders with a trailing '/'."""
    for dirpath, dirnames, filenames in os.walk(folder):
        rel = Path(dirpath).relative_to(folder)
        for d in list(dirnames):
            if os.path.islink(os.path.join(dirpath, d)):  # never walk into a link
                dirnames.remove(d)
                filenames.append(d)
        yield from ((rel / d).as_posix() + "/" for d in dirnames)
        yield from ((rel / f).as_posix() for f in filenames if (rel / f).as_posix() != MANIFEST)


def _manifest(folder: Path) -> set[str] | None:
    """The entries listed by `folder`'s manifest; None when it has none (or not sgloc's)."""
    try:
        data = json.loads((folder / MANIFEST).read_text())
        if data.get("schema") == MANIFEST_SCHEMA:
            return {str(e) for e in data["files"]}
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        pass
    return None


@contextlib.contextmanager
def claimed_output(out: str | Path, option: str = "--out") -> Iterator[Path]:
    """Hold `out`'s lock (a hidden `.NAME.lock` file beside it, removed at the end) for the
    block: another run claiming the same path meanwhile is refused at once (OutputPathError).
    Leftovers of writers to `out` whose process is gone are removed first. Nested claims of
    one path in one process share the lock."""
    out = Path(out)
    key = str(_real(out))
    if key in _HELD:
        _HELD[key] += 1
        try:
            yield out
        finally:
            _HELD[key] -= 1
        return
    interrupts.hold()  # the lock and the folders made for it are undone whatever lands
    try:
        interrupts.check()
        created = _make_parents(out.parent)
        try:
            fd, lock = _lock(out, option)
        except BaseException:
            _remove_empty(created)
            raise
    except BaseException:
        interrupts.release()
        raise
    _HELD[key] = 1
    try:
        interrupts.release()
        _remove_stale(out)
        yield out
    finally:
        with interrupts.held():
            del _HELD[key]
            lock.unlink(missing_ok=True)
            os.close(fd)
            _remove_empty(created)


#: The outputs this process holds the lock of (real path -> nesting depth).
_HELD: dict[str, int] = {}


def _lock(out: Path, option: str) -> tuple[int, Path]:
    """(open file, path) of `out`'s lock file, locked; OutputPathError when another run has
    it. A lock file removed by its last holder between our open and lock is opened again.
    Without fcntl (Windows) the file is made but not locked."""
    try:
        import fcntl
    except ImportError:
        fcntl = None
    lock = out.parent / f".{out.name[:100]}.lock"
    for _ in range(5):
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as e:
            raise SglocError(f"{out}: cannot write ({e.strerror or e}); {_hint(e)}") from None
        try:
            if fcntl is not None:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise OutputPathError(f"{out}: another sgloc run is writing it now; wait for that "
                                  f"run to end or give another path for {option}.") from None
        with contextlib.suppress(OSError):
            if os.stat(lock).st_ino == os.fstat(fd).st_ino:
                return fd, lock
        os.close(fd)
    raise OutputPathError(f"{out}: other sgloc runs keep writing it; give another {option}.")


def _make_parents(folder: Path) -> list[Path]:
    """Create `folder` and its missing parents; the ones created, deepest first."""
    missing = []
    for p in [folder, *folder.parents]:
        if p.exists():
            break
        missing.append(p)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise SglocError(
            f"{folder}: cannot make the folder ({e.strerror or e}); {_hint(e)}"
        ) from None
    return missing


def _remove_empty(folders: list[Path]) -> None:
    """Remove the folders (deepest first) a failed write created, where they are still empty."""
    for p in folders:
        with contextlib.suppress(OSError):
            p.rmdir()


def _remove_stale(out: Path) -> None:
    """Remove the hidden staging / set-aside folders and files of earlier writers of `out`
    whose process is gone (killed before it could clean up)."""
    with contextlib.suppress(OSError):
        for entry in out.parent.iterdir():
            m = _SIDE.match(entry.name)
            if m and m["name"] == out.name[:100] and not _alive(int(m["pid"])):
                if entry.is_dir() and not entry.is_symlink():
                    shutil.rmtree(entry, ignore_errors=True)
                else:
                    entry.unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process: alive
        return True
    return True


def _umask_mode(mode: int) -> int:
    """`mode` with the process's umask applied (what a plain mkdir / open would give)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mode & ~mask


@contextlib.contextmanager
def staged_folder(
    out: str | Path, inputs: Sequence[str | Path | None] = (), option: str = "--out"
) -> Iterator[Path]:
    """Write the results folder `out` atomically: yields an empty hidden sibling folder to write
    into, which becomes `out` (with a MANIFEST listing its entries, permissions after the
    umask) once the block ends without error. `out` may be absent, an empty folder or an
    earlier results folder of sgloc; anything else is refused before the block runs
    (`check_output_path`). On an error or interruption nothing of the block's writing stays and
    `out` is as before; an OSError becomes an SglocError naming the file."""
    out = Path(out)
    check_output_path(out, inputs, option)
    with claimed_output(out, option):
        stage = None
        try:
            with interrupts.held():
                stage = Path(tempfile.mkdtemp(
                    prefix=f".{out.name[:100]}.partial-{os.getpid()}-", dir=out.parent))
            yield stage
            with _signals_held():
                _commit(stage, out, option)
                stage = None
                written(out)
        except OSError as e:
            raise SglocError(_write_error(e, stage, out)) from None
        finally:
            with interrupts.held():
                if stage is not None:
                    shutil.rmtree(stage, ignore_errors=True)


def _commit(stage: Path, out: Path, option: str) -> None:
    """List the stage's entries in its manifest, then move it into place: renamed to `out`
    (an earlier results folder is set aside first and removed after), or its entries moved
    into `out` when that is an existing empty folder."""
    entries = sorted(_entries(stage))
    manifest = {"schema": MANIFEST_SCHEMA, "written_by": "sgloc", "files": entries}
    (stage / MANIFEST).write_text(json.dumps(manifest, indent=1) + "\n")
    os.chmod(stage, _umask_mode(0o777))
    state = _replaceable_folder(out, option)  # again, under the lock: it may have changed
    if state == "absent":
        os.rename(stage, out)
    elif state == "empty":  # written into, keeping the folder the user made; the manifest
        os.rename(stage / MANIFEST, out / MANIFEST)  # first, so a part is still sgloc's
        for name in sorted(os.listdir(stage)):
            os.rename(stage / name, out / name)
        stage.rmdir()
    else:
        aside = Path(tempfile.mkdtemp(prefix=f".{out.name[:100]}.old-{os.getpid()}-",
                                      dir=out.parent))
        os.rename(out, aside / out.name)
        try:
            os.rename(stage, out)
        except OSError:
            os.rename(aside / out.name, out)
            raise
        finally:
            shutil.rmtree(aside, ignore_errors=True)


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """SIGINT / SIGTERM wait for the end of the block (a few renames), so that an output is
    moved into place whole or not at all; in the `sgloc` program, a signal received before
    (even one whose raise was lost) stops the block before it moves anything."""
    with interrupts.held():
        interrupts.check()
        yield


@contextlib.contextmanager
def staged_file(
    path: str | Path, inputs: Sequence[str | Path | None] = (), option: str = "--out",
    ours: Callable[[Path], bool] | None = None,
) -> Iterator[Path]:
    """Write the single file `path` atomically: yields a hidden sibling path (same suffix) to
    write, renamed to `path` (permissions after the umask) once the block ends without error.
    An existing `path` is replaced only when `ours(path)` says sgloc wrote it
    (`check_output_path`); an OSError becomes an SglocError naming `path`."""
    path = Path(path)
    check_output_path(path, inputs, option, folder=False, ours=ours)
    with claimed_output(path, option):
        tmp: Path | None = None
        try:
            with interrupts.held():
                fd, name = tempfile.mkstemp(prefix=f".{path.name[:100]}.partial-{os.getpid()}-",
                                            suffix=path.suffix, dir=path.parent)
                os.close(fd)
                tmp = Path(name)
            yield tmp
            os.chmod(tmp, _umask_mode(0o666))
            check_output_path(path, (), option, folder=False, ours=ours)
            with _signals_held():
                os.replace(tmp, path)
                tmp = None
                written(path)
        except OSError as e:
            raise SglocError(f"{path}: cannot write ({e.strerror or e}); " + _hint(e)) from None
        finally:
            with interrupts.held():
                if tmp is not None:
                    tmp.unlink(missing_ok=True)


def write_text_atomic(
    path: str | Path, text: str, inputs: Sequence[str | Path | None] = (), option: str = "--json",
    ours: Callable[[Path], bool] | None = None,
) -> Path:
    """Write `text` to the single file `path` through `staged_file`: the file holds the whole
    text or is as before."""
    with staged_file(path, inputs, option, ours) as tmp:
        tmp.write_text(text)
    return Path(path)


#: The mark of the pictures sgloc draws, in each format's own field for the program that made
#: it (`sgloc.io.pictures.save_picture`); `is_sgloc_picture` reads it back.
PICTURE_MARK = "sgloc"
#: EXIF tag 0x0131, Software: the mark of JPEG, TIFF, WebP and AVIF pictures.
EXIF_SOFTWARE = 0x0131
_SVG_MARK = re.compile(rb"<dc:creator>\s*<cc:Agent>\s*<dc:title>" + PICTURE_MARK.encode()
                       + rb"</dc:title>")


def is_sgloc_picture(path: Path) -> bool:
    """True if `path` is a picture sgloc drew, in any format it draws: PNG (Software text), PDF,
    PostScript and SVG (creator), JPEG, TIFF, WebP, AVIF (EXIF Software) or GIF (comment)."""
    mark = PICTURE_MARK.encode()
    try:
        with open(path, "rb") as f:
            head = f.read(1 << 16)
            f.seek(max(0, os.fstat(f.fileno()).st_size - (1 << 16)))
            tail = f.read()
    except OSError:
        return False
    if head[:8] == b"\x89PNG\r\n\x1a\n":
        return b"tEXtSoftware\x00" + mark in head
    if head[:5] == b"%PDF-":  # the document information comes last
        return b"/Creator (" + mark + b")" in tail
    if head[:4] == b"%!PS":
        return re.search(rb"^%%Creator: " + mark + rb"\r?$", head, re.M) is not None
    if head[:2] == b"\x1f\x8b":  # svgz
        head = _gunzipped_head(path)
    if head.lstrip()[:5] in (b"<?xml", b"<svg "):
        return _SVG_MARK.search(head) is not None
    return _pil_mark(path) == PICTURE_MARK


def _gunzipped_head(path: Path) -> bytes:
    import gzip

    try:
        with gzip.open(path, "rb") as f:
            return f.read(1 << 16)
    except (OSError, EOFError):
        return b""


def _pil_mark(path: Path) -> str | None:
    """The mark of a raster picture Pillow reads (EXIF Software, or a GIF's comment)."""
    import warnings

    from PIL import Image

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a user's huge or odd picture: not ours either way
            with Image.open(path) as im:
                if im.format == "GIF":
                    comment = im.info.get("comment")
                    return comment.decode("utf-8", "replace") if comment else None
                software = im.getexif().get(EXIF_SOFTWARE)
                return software if isinstance(software, str) else None
    except Exception:  # anything Pillow cannot read is not a picture sgloc drew
        return None


#: The outputs this process has moved into place (for the interruption message).
_WRITTEN: list[Path] = []


def written(path: Path | None = None) -> list[Path]:
    """Record `path` as an output moved into place; the outputs recorded so far."""
    if path is not None:
        _WRITTEN.append(Path(path))
    return list(_WRITTEN)


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


@contextlib.contextmanager
def naming(path: str | Path) -> Iterator[None]:
    """An OSError in the block names `path` when it names no file (a write to a full disk)."""
    try:
        yield
    except OSError as e:
        if not e.filename:
            e.filename = str(path)
        raise
