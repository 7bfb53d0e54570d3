"""The typer app and the entry point that turns every user error into one line and an exit code.

Exit codes: 0 localized (or the command did its work); 1 ran correctly but not localized (a valid
answer: the maps gave too little evidence); 2 bad input or usage (one `error:` line, no
traceback); 130 interrupted (Ctrl-C, SIGINT); 143 terminated (SIGTERM).
"""

from __future__ import annotations

import contextlib
import gc
import os
import signal
import sys
from importlib.metadata import PackageNotFoundError, version

import typer

from sgloc.errors import SglocError
from sgloc.runtime import interrupts
from sgloc.runtime.interrupts import Interrupted

app = typer.Typer(
    name="sgloc",
    help="Multi-robot global localization on semantic graphs.\n\n"
    "Examples: sgloc localize --example --out results/example   |   sgloc demo\n\n"
    "Exit codes: 0 done, 1 not localized, 2 bad input or usage.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)



def _plain_help_types() -> None:
    """Help without `<bool>` after flags (--help, --version, --example) and with `TYPE ...`
    rather than `<list[TYPE]>` after repeatable options (typer's rich help shows both)."""
    try:
        from typer.core import TyperOption
    except ImportError:  # another typer: its own help
        return
    shown = getattr(TyperOption, "display_type_rich", None)
    if shown is None or getattr(shown, "sgloc_plain", False):
        return

    def display_type_rich(self, ctx):
        if self.metavar is None and getattr(self, "is_flag", False):
            return None
        label = shown(self, ctx)
        if self.metavar is None and getattr(self, "multiple", False) and label:
            label = label.replace("<list[", "<").replace("]>", "> ...")
        return label

    display_type_rich.sgloc_plain = True
    TyperOption.display_type_rich = display_type_rich


_plain_help_types()


def _plain_usage() -> None:
    """Usage lines in the usual form: `QUERY`, `[SOURCE]...`, `GRAPH...` (typer writes a
    required argument `{name}`)."""
    try:
        from typer.core import TyperArgument
    except ImportError:
        return
    if not hasattr(TyperArgument, "_usage_display_name"):
        return

    def usage_name(self) -> str:
        name = (self.metavar or self.name or "").upper()
        name = name if self.required else f"[{name}]"
        return name + ("..." if self.nargs != 1 else "")

    TyperArgument._usage_display_name = usage_name


_plain_usage()

EXIT_OK = 0
EXIT_NOT_LOCALIZED = 1
EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 143


def _interrupted(e: BaseException, before: int) -> int:
    """Print what an interruption left (one line); return the exit code."""
    from sgloc.io.files import written

    signum = getattr(e, "signum", 0) or interrupts.received() or signal.SIGINT
    done = written()[before:]
    how = "terminated (SIGTERM)" if signum == signal.SIGTERM else "interrupted (SIGINT)"
    what = ("nothing was written" if not done
            else "it had written " + ", ".join(str(p) for p in done) + "; nothing else was")
    typer.echo(f"{how}; {what}.", err=True)
    return EXIT_TERMINATED if signum == signal.SIGTERM else EXIT_INTERRUPTED


def _package_version() -> str:
    try:
        return version("sgloc")
    except PackageNotFoundError:  # running from a source tree that is not installed
        return "unknown"


def _version_callback(value: bool) -> None:
    if value:
        typer.echo(f"sgloc {_package_version()}")
        raise typer.Exit(EXIT_OK)


@app.callback()
def _root(
    show_version: bool = typer.Option(
        False,
        "--version",
        callback=_version_callback,
        is_eager=True,
        help="Print the version and exit.",
    ),
) -> None:
    """Multi-robot global localization on semantic graphs."""


def fail(message: str) -> typer.Exit:
    """Print `error: message` on one line to stderr; return the Exit to raise (code 2)."""
    typer.echo(f"error: {_one_line(message)}", err=True)
    return typer.Exit(EXIT_USER_ERROR)


def compile_note() -> str:
    """A line saying how long this run compiled the numba kernels on first use (once per
    install; later runs load them from the cache), time the stage times shown leave out; the
    empty string when nothing compiled."""
    from sgloc.kernels import compile_seconds

    wall = compile_seconds()[0]
    if wall < 0.05:
        return ""
    return (f"compiling the numba kernels on first use: {wall:.1f} s more, not in the times "
            "above (later runs load them from the cache)")


def not_localized(message: str) -> typer.Exit:
    """Print `not localized: message` to stderr; return the Exit to raise (code 1)."""
    typer.echo(f"not localized: {_one_line(message)}", err=True)
    return typer.Exit(EXIT_NOT_LOCALIZED)


def _one_line(message: str) -> str:
    return " ".join(str(message).split())


def _is_framework_exception(e: BaseException) -> bool:
    """True for the exceptions of click or of typer's bundled click copy (matched by module, so
    that any typer/click version pairing works without importing click here)."""
    module = type(e).__module__ or ""
    return module.split(".")[0] in {"click", "typer"}


def _framework_exit(e: BaseException, before: int = 0) -> int:
    """Print a click/typer exception the one-line way; return its exit code."""
    name = type(e).__name__
    if name == "Abort":  # click's wrapper of Ctrl-C
        return _interrupted(e, before)
    if name == "NoArgsIsHelpError":  # bare `sgloc` or `sgloc CMD`: the help is the message
        typer.echo(e.format_message(), err=True)
        return EXIT_USER_ERROR
    code = getattr(e, "exit_code", None)
    if not hasattr(e, "format_message"):  # Exit: a plain exit code
        return int(code or 0)
    ctx = getattr(e, "ctx", None)
    if ctx is not None:
        typer.echo(ctx.get_usage(), err=True)
    hint = f" (see '{ctx.command_path} --help')" if ctx is not None else ""
    typer.echo(f"error: {_one_line(e.format_message())}{hint}", err=True)
    return int(code if code is not None else EXIT_USER_ERROR)


def _one_line_summaries(typer_app: typer.Typer) -> None:
    """Each command's help as paragraphs of one line each, its summary in the command list the
    first (rich help keeps a docstring's line breaks, cutting sentences)."""
    import inspect

    for info in typer_app.registered_commands:
        doc = inspect.cleandoc(info.help or (info.callback.__doc__ if info.callback else "") or "")
        if not doc:
            continue
        paragraphs = [" ".join(p.split()) for p in doc.split("\n\n")]
        info.help = "\n\n".join(paragraphs)
        if info.short_help is None:
            info.short_help = paragraphs[0]
    for group in typer_app.registered_groups:
        if group.typer_instance is not None:
            _one_line_summaries(group.typer_instance)


def _as_program() -> None:
    """Collector settings of the `sgloc` program, a short-lived process (not of `main(argv)`
    called from Python). Its start-up (numba, scipy, typer) leaves ~140,000 long-lived objects,
    and every full collection walks them all (~0.1 s each, several per run): full collections
    come after 100 collections of the middle generation instead of 10. The young generations,
    where most cyclic garbage dies, are collected as before."""
    young, middle, _ = gc.get_threshold()
    gc.set_threshold(young, middle, 100)


def _exit(rc: int) -> None:
    """Leave the `sgloc` program with exit code `rc`; a signal from now on is ignored (the run
    has ended: its outcome is `rc`, its outputs complete). The objects alive now are frozen first:
    the interpreter's last collections at exit then skip them (~0.25 s saved; the process ends,
    so nothing is left uncollected for long; exit handlers run as usual, except after an
    interruption)."""
    interrupts.ignore()  # a signal now comes after the run's end (its outputs are complete)
    if rc in (EXIT_INTERRUPTED, EXIT_TERMINATED):
        # An interrupted run has printed its line and written nothing: the interpreter's
        # finalisation is skipped, since a signal that landed inside a compiled module's start
        # can leave that module unable to finalise (a crash at exit after the right message).
        # Worker processes end on their own once this process is gone (sgloc.runtime.workers).
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        os._exit(rc)
    gc.freeze()
    sys.exit(rc)


def main(argv: list[str] | None = None) -> int:
    """Console entry point. A user error (SglocError, bad usage) becomes one line on stderr and
    exit 2; "not localized" exits 1; no traceback reaches the user for either. Ctrl-C or SIGTERM
    at any moment ends it with 130 or 143, one line, and no output moved into place after the
    signal (`sgloc.runtime.interrupts`). Without `argv` (the `sgloc` program, `python -m
    sgloc`) the arguments are the process's and it exits."""
    from sgloc.io.files import written

    if argv is None:
        _as_program()
    before = len(written())
    previous = interrupts.install()
    try:
        try:
            interrupts.check()  # a signal while the program started
            rc = _run(argv, before)
        except Interrupted as e:  # landed after the command's own handling
            rc = _interrupted(e, before)
        finally:
            interrupts.hold()  # from here on a signal is only recorded
        signum = interrupts.received()
        if signum and rc not in (EXIT_INTERRUPTED, EXIT_TERMINATED):  # its raise was lost
            rc = _interrupted(Interrupted(signum), before)
    finally:
        if argv is not None:  # called from Python: the caller's handlers again
            interrupts.uninstall(previous)
    rc = int(rc) if isinstance(rc, int) else EXIT_OK
    if argv is None:
        _exit(rc)  # signals stay recorded only, up to the process's end
    return rc


def _run(argv: list[str] | None, before: int) -> int:
    """Run the command line `argv`; its exit code, every error printed as one line."""
    _one_line_summaries(app)
    try:
        rc = app(args=argv, prog_name="sgloc", standalone_mode=False)
    except SglocError as e:
        typer.echo(f"error: {_one_line(e)}", err=True)
        rc = EXIT_USER_ERROR
    except (KeyboardInterrupt, Interrupted) as e:
        rc = _interrupted(e, before)
    except OSError as e:  # the file system refused an input or output path
        where = f"{e.filename}: " if e.filename else ""
        typer.echo(
            f"error: {where}{e.strerror or e}; check the path and its permissions.", err=True
        )
        rc = EXIT_USER_ERROR
    except Exception as e:
        interrupted = interrupts.in_chain(e)  # a compiled library turned it into its own error
        if interrupted is not None:
            return _interrupted(interrupted, before)
        if not _is_framework_exception(e):
            raise
        rc = _framework_exit(e, before)
    return rc
