"""Command-line interface: `sgloc demo | localize | ...`. Each command lives in its own module
and registers itself on `app` when imported here. In the `sgloc` program, Ctrl-C and SIGTERM
are recorded from this module's first lines on, before the heavy imports below, and end the
run as soon as it starts (`sgloc.runtime.interrupts`)."""

import os
import sys

from sgloc.runtime import interrupts

#: The file names of the `sgloc` program's script (console script, Windows launcher).
_PROGRAMS = {"sgloc", "sgloc-script.py", "sgloc.exe"}


def _in_program() -> bool:
    """True in the `sgloc` program (not when another program imports sgloc.cli)."""
    script = getattr(sys.modules.get("__main__"), "__file__", None) or ""
    return os.path.basename(script) in _PROGRAMS


if _in_program():
    interrupts.install_early()

import sgloc.cli.build_graph_cmd  # noqa: E402, F401
import sgloc.cli.data_cmd  # noqa: E402, F401
import sgloc.cli.experiment_cmd  # noqa: E402, F401
import sgloc.cli.fleet_cmd  # noqa: E402, F401
import sgloc.cli.replay_cmd  # noqa: E402, F401
import sgloc.cli.serve_cmd  # noqa: E402, F401
import sgloc.cli.warmup_cmd  # noqa: E402, F401
from sgloc.cli import demo_cmd, localize_cmd  # noqa: E402, F401  (registers the commands)
from sgloc.cli.app import app, main  # noqa: E402

__all__ = ["app", "main"]
