"""Command-line interface: `sgloc demo | localize | ...`. Each command lives in its own module
and registers itself on `app` when imported here."""

from sgloc.cli import demo_cmd, localize_cmd  # noqa: F401  (registers the commands)
from sgloc.cli.app import app, main

__all__ = ["app", "main"]
