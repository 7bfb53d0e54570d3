"""`sgloc warmup`: compile every numba kernel into the cache now, not on first use."""

from __future__ import annotations

import typer

from sgloc.cli.app import app


@app.command("warmup")
def warmup_cmd() -> None:
    """Compile every compiled kernel into numba's cache now (once per install; later runs only
    load them). For container images and read-only installs: run it where the cache folder is
    writable, e.g. as a build step, so that no user's first call compiles. The cache is the
    package's kernels/__pycache__ when writable, else numba's per-user cache folder;
    NUMBA_CACHE_DIR overrides both.

    Example: sgloc warmup    (in a Dockerfile: RUN sgloc warmup)
    """
    from sgloc.warmup import warm_up

    report = warm_up()
    if report.compile_seconds > 0:
        what = (f"compiled in {report.compile_seconds:.1f} s "
                f"({report.compile_cpu_seconds:.1f} s CPU)")  # fmt: skip
    else:
        what = "already compiled: loaded from the cache"
    typer.echo(f"kernels {what}; {len(report.modules)} kernel modules, cache {report.cache_dir}")
