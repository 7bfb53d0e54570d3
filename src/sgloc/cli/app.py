"""The typer app and the entry point that turns user errors into one line and exit code 2."""

from __future__ import annotations

import sys

import click
import typer

from sgloc.errors import SglocError

app = typer.Typer(
    name="sgloc",
    help="Multi-robot global localization on semantic graphs.\n\n"
    "Example: sgloc demo   |   sgloc localize cloud1.pcd cloud2.pcd --json result.json",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

EXIT_USER_ERROR = 2


def fail(message: str) -> typer.Exit:
    """Print `error: message` on one line to stderr; return the Exit to raise (code 2)."""
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(EXIT_USER_ERROR)


def main(argv: list[str] | None = None) -> int:
    """Console entry point: run the CLI; an SglocError becomes one line on stderr and exit 2."""
    try:
        rc = app(args=argv, standalone_mode=False)
    except SglocError as e:
        typer.echo(f"error: {e}", err=True)
        rc = EXIT_USER_ERROR
    except click.exceptions.Abort:
        typer.echo("aborted", err=True)
        rc = 130
    except click.exceptions.ClickException as e:
        e.show()
        rc = e.exit_code
    except click.exceptions.Exit as e:
        rc = e.exit_code
    if argv is None:
        sys.exit(rc or 0)
    return int(rc or 0)
