"""The commands' outputs: each output path is checked (`sgloc.io.files.check_output_path`) and
claimed (locked against another run) when the command starts, before any work."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import typer

from sgloc.errors import OutputPathError
from sgloc.io.files import check_output_path, claimed_output


def claim_output(
    ctx: typer.Context,
    out: Path | None,
    inputs: Sequence[Path | str | None] = (),
    option: str = "--out",
    folder: bool = True,
    ours: Callable[[Path], bool] | None = None,
) -> Path | None:
    """Refuse `out` now if sgloc may not write it (OutputPathError: the CLI's one line), or if
    it is, holds or lies in another output of the command; hold its lock until the command
    ends, so that a second run writing the same path is refused at once. None: no output."""
    if out is None:
        return None
    claimed = ctx.meta.setdefault("sgloc.outputs", [])
    here = out.resolve()
    for other, other_option in claimed:  # first: an earlier output's lock may lie in `out`
        if here == other or here.is_relative_to(other) or other.is_relative_to(here):
            raise OutputPathError(f"{out}: {option} and {other_option} would overlap; give "
                                  "each output its own path.")
    check_output_path(out, inputs, option, folder, ours)
    ctx.with_resource(claimed_output(out, option))
    claimed.append((here, option))
    return out
