"""Where numba caches the compiled kernels when neither the package folder nor the per-user cache
folder is writable (a read-only install in a container or a system install): a folder of the
temporary directory, else no cache at all; said once on stderr. Imports numba only in the last
case."""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

#: Set in the environment once the fallback was said, so that worker processes stay quiet.
_SAID = "SGLOC_KERNEL_CACHE_SAID"


def _writable(folder: Path) -> bool:
    """Whether numba could cache into `folder` (its own test: create it, write a file there)."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError:
        return False
    return True


def _user_cache_dir() -> Path:
    """numba's per-user cache folder (`appdirs.user_cache_dir`, appname "numba")."""
    if sys.platform == "darwin":
        return Path.home() / "Library" / "Caches" / "numba"
    if sys.platform == "win32":
        base = os.environ.get("LOCALAPPDATA") or str(Path.home() / "AppData" / "Local")
        return Path(base) / "numba" / "Cache"
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "numba"


def _numba_would_cache() -> bool:
    """Whether one of numba's own cache locators finds a writable folder."""
    candidates = [Path(__file__).parent / "__pycache__"]
    if os.environ.get("NUMBA_CACHE_DIR"):
        candidates.insert(0, Path(os.environ["NUMBA_CACHE_DIR"]))
    try:
        candidates.append(_user_cache_dir())
    except RuntimeError:  # no home directory
        pass
    return any(_writable(c) for c in candidates)


def _say(message: str) -> None:
    if not os.environ.get(_SAID):
        print(f"sgloc: {message}", file=sys.stderr)
        os.environ[_SAID] = "1"


def _run_uncached() -> None:
    """Compile sgloc's kernels without a cache: numba's caching is skipped for them only."""
    from numba.core.dispatcher import Dispatcher

    enable = Dispatcher.enable_caching
    if getattr(enable, "sgloc_uncached", False):
        return

    def enable_caching(self):
        from sgloc.kernels import MODULES

        if getattr(self.py_func, "__module__", "") not in MODULES:
            enable(self)

    enable_caching.sgloc_uncached = True
    Dispatcher.enable_caching = enable_caching


def ensure_cache_dir() -> None:
    """Make sure the compiled kernels can load: if numba would find no writable cache folder,
    point it at one in the temporary directory (`NUMBA_CACHE_DIR`), or run them uncached."""
    if _numba_would_cache():
        return
    user = getattr(os, "getuid", lambda: 0)()
    fallback = Path(tempfile.gettempdir()) / f"sgloc-numba-cache-{user}"
    if _writable(fallback):
        os.environ["NUMBA_CACHE_DIR"] = str(fallback)
        if "numba" in sys.modules:  # numba read the environment already
            from numba.core import config

            config.CACHE_DIR = str(fallback)
        _say(f"no writable cache folder for the compiled kernels; caching them in {fallback}")
        return
    _run_uncached()
    _say(
        "no writable cache folder for the compiled kernels; compiling them in every process "
        "(set NUMBA_CACHE_DIR to a writable folder to cache them)"
    )
