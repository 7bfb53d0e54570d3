"""`sgloc data list | fetch NAME | path NAME`: the data sets, where they are, how to get them."""

from __future__ import annotations

from pathlib import Path

import typer

from sgloc.cli.app import app
from sgloc.datasets.downloads import (
    DOWNLOADS,
    dataset,
    fetch,
    fetch_dir,
    find_dataset,
    is_complete,
    sample_dir,
)

data_app = typer.Typer(
    help="Data sets: list them, download one (pinned sources, sha256-checked), show its folder.",
    no_args_is_help=True,
)
app.add_typer(data_app, name="data")


@data_app.command("list")
def list_cmd() -> None:
    """List the data sets, whether each is here and where.

    Example: sgloc data list
    """
    for ds in DOWNLOADS.values():
        folder = find_dataset(ds.name)
        if folder is not None and is_complete(ds.name, folder):
            shipped = ds.shipped and folder == sample_dir(ds.name)
            status = f"shipped in {folder}" if shipped else f"in {folder}"
        else:
            status = f"not here: sgloc data fetch {ds.name}"
        typer.echo(f"{ds.name:<11} {ds.size:>7}  {ds.licence:<16} {ds.description}")
        typer.echo(f"{'':<11} {'':>7}  {status}")
    typer.echo(f"downloads go to {fetch_dir()} (set SGLOC_DATA to use another folder)")


@data_app.command("fetch")
def fetch_cmd(
    name: str = typer.Argument(..., help=f"Data set: {' | '.join(DOWNLOADS)}."),
    dest: Path | None = typer.Option(
        None, help="Folder to put NAME/ in (default: $SGLOC_DATA, else the per-user data folder)."
    ),
) -> None:
    """Download a data set from its public sources at pinned commits, checking every file's
    sha256, and show its licence.

    Example: sgloc data fetch kitti00
    """
    ds = dataset(name)
    typer.echo(f"{ds.name}: {ds.description}", err=True)
    typer.echo(f"licence: {ds.licence}. {ds.licence_detail}", err=True)
    for f in ds.files:
        typer.echo(f"  {f.name:<28} from {f.repo} @ {f.commit[:10]}: {f.path}", err=True)
    folder = fetch(ds.name, dest)
    typer.echo(f"{ds.name} is in {folder} (every file matches its sha256)", err=True)
    typer.echo(str(folder))


@data_app.command("path")
def path_cmd(name: str = typer.Argument(..., help=f"Data set: {' | '.join(DOWNLOADS)}.")) -> None:
    """Print the folder of a data set (for scripts: `ls "$(sgloc data path kitti00)"`).

    Example: sgloc data path airsim_guo
    """
    from sgloc.datasets.downloads import dataset_dir

    typer.echo(str(dataset_dir(name)))
