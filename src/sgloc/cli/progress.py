"""The commands' progress bars: a rich bar fed by a library function's `progress(done, total,
phase)` reports."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from rich.console import Console
from rich.progress import Progress, ProgressColumn

#: What a library function calls as its work advances: done of total units in a phase.
Report = Callable[..., None]


@contextmanager
def progress_bar(
    *columns: str | ProgressColumn,
    console: Console,
    disable: bool = False,
    start: bool = False,
    first: str | None = None,
    per_phase: bool = False,
) -> Iterator[Report]:
    """A `progress(done, total, phase="")` callback drawing `columns`. The display starts at
    the first report (an error before it prints no bar), or at once with `start`, or at once
    with a bar for the phase `first` (total unknown). `per_phase`: a bar per phase; else one
    bar whose description is the phase."""
    bar = Progress(*columns, console=console, disable=disable)
    tasks: dict[str, Any] = {}
    started = start or first is not None
    if started:
        bar.start()
    if first is not None:
        tasks[""] = bar.add_task(first, total=None)

    def report(done: int, total: int | None, phase: str = "") -> None:
        nonlocal started
        if not started:
            bar.start()
            started = True
        key = phase if per_phase else ""
        if key not in tasks:
            tasks[key] = bar.add_task(phase, total=total)
        update = {"description": phase} if phase else {}
        bar.update(tasks[key], completed=done, total=total, **update)

    try:
        yield report
    finally:
        if started:
            bar.stop()
