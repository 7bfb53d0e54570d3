"""Command-line interface: `sgloc demo | localize | ...`. Each command lives in its own module
and registers itself on `app` when imported here."""

import sgloc.cli.build_graph_cmd  # noqa: F401
import sgloc.cli.data_cmd  # noqa: F401
import sgloc.cli.experiment_cmd  # noqa: F401
import sgloc.cli.fleet_cmd  # noqa: F401
import sgloc.cli.replay_cmd  # noqa: F401
import sgloc.cli.serve_cmd  # noqa: F401
import sgloc.cli.warmup_cmd  # noqa: F401
from sgloc.cli import demo_cmd, localize_cmd  # noqa: F401  (registers the commands)
from sgloc.cli.app import app, main

__all__ = ["app", "main"]
