"""Optional dependencies: import one or raise a one-line error naming the extra to install."""

from __future__ import annotations

import importlib
from types import ModuleType

from sgloc.errors import SglocError


class MissingExtraError(SglocError):
    """A feature needs an optional dependency that is not installed."""


def require(module: str, extra: str, feature: str) -> ModuleType:
    """Import `module`, or raise MissingExtraError naming `pip install 'sgloc[extra]'`."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise MissingExtraError(
            f"{feature} needs {module.split('.')[0]}, which is not installed: "
            f"pip install 'sgloc[{extra}]'"
        ) from None
