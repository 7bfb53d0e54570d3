"""`sgloc replay`: stream recorded multi-robot runs through an online session."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn
from rich.table import Table

from sgloc.cli.app import app, not_localized
from sgloc.cli.options import (
    CLASSES_HELP,
    ConfigFile,
    OnlineSettings,
    Preset,
    localizer_config,
    split_online_settings,
)
from sgloc.cli.outputs import claim_output
from sgloc.cli.progress import progress_bar
from sgloc.optional import require
from sgloc.replay.job import replay_job

Sources = Annotated[list[Path] | None, typer.Argument(
    metavar="SOURCE", help="A plain layout folder (one folder per robot: "
    "odometry.tum, objects.csv), a rosbag2 folder or an .mcap/.db3 file; or one bag (or "
    "robot folder) per robot, each robot named by its file's stem."
)]
Robot = Annotated[list[str] | None, typer.Option(
    "--robot", metavar="NAME=PATH", help="A robot's own bag (or robot folder), the "
    "robot named NAME (repeatable; with or instead of SOURCES)."
)]
Kitti00 = Annotated[bool, typer.Option("--kitti00", help="Replay KITTI 00 (data `kitti00`) "
                                       "cut into --robots consecutive segments.")]
City = Annotated[bool, typer.Option("--city", help="Replay the synthetic city's two routes cut "
                                    "into --robots robots (objects only, no rendering).")]
Robots = Annotated[int, typer.Option(min=1, help="Robots to cut --kitti00 / --city into.")]
Scans = Annotated[str, typer.Option(help="KITTI 00 scans to cut (--kitti00), first-last.")]
Every = Annotated[int, typer.Option(min=1, help="Use every n-th scan as a keyframe (--kitti00).")]
Poses = Annotated[str, typer.Option(help="KITTI 00 poses used as the robots' odometry and as "
                                    "the truth (--kitti00): raw (poses_00.txt) or refined (made "
                                    "consistent with the refined revisit transforms; needs "
                                    "gtsam).")]
Seed = Annotated[int, typer.Option(min=0, help="City (--city) and session seed.")]
Out = Annotated[Path, typer.Option(help="Results folder: a new or empty folder, or an earlier "
                                   "results folder of sgloc (replaced).")]
OutBag = Annotated[Path | None, typer.Option(help="Also write the fleet frames as "
                                             "geometry_msgs/TransformStamped into this ROS 2 bag "
                                             "folder: new, empty, or an earlier bag of sgloc "
                                             "(replaced).")]
Classes = Annotated[Path | None, typer.Option("--class-table", "--classes", help=f"{CLASSES_HELP} "
                                              "for class names in objects.csv or marker "
                                              "namespaces.")]
OdomTopic = Annotated[str | None, typer.Option(help="Odometry topic template (default "
                                               "/{robot}/odom), or a plain topic name (/odom) "
                                               "for bags of one robot each.")]
ObjectsTopic = Annotated[str | None, typer.Option(help="Object topic template (default "
                                                  "/{robot}/objects), or a plain topic name.")]
Root = Annotated[str | None, typer.Option(help="Robot whose odometry frame is the fleet frame "
                                          "(default: the first to send a keyframe).")]
Backend = Annotated[str, typer.Option(help="Fleet back-end: keyframes (a pose graph over every "
                                      "keyframe: corrects drifting odometry; "
                                      "docs/online_session.md) or robots (one rigid frame per "
                                      "robot).")]
Quiet = Annotated[bool, typer.Option("--quiet", help="No progress bar or table.")]


@app.command("replay")
def replay_cmd(
    ctx: typer.Context,
    sources: Sources = None,
    robot: Robot = None,
    kitti00: Kitti00 = False,
    city: City = False,
    robots: Robots = 4,
    scans: Scans = "0-2999",
    every: Every = 1,
    poses: Poses = "raw",
    seed: Seed = 0,
    out: Out = Path("results/replay"),
    out_bag: OutBag = None,
    classes: Classes = None,
    odom_topic: OdomTopic = None,
    objects_topic: ObjectsTopic = None,
    root: Root = None,
    preset: Preset = None,
    config: ConfigFile = None,
    setting: OnlineSettings = None,
    backend: Backend = "keyframes",
    quiet: Quiet = False,
) -> None:
    """Stream every robot's keyframes, interleaved by stamp, through one online session and write
    the fleet: fleet/<robot>.tum, maps/<robot>.json, merged.json, events.csv, links.g2o,
    g2o_keyframes.csv, summary.json, timeline.png, fleet.png.

    Examples: sgloc replay runs/campus --out results/campus --out-bag results/campus_bag
    |   sgloc replay alpha.mcap beta.mcap --odom-topic /odom --objects-topic /objects
    |   sgloc replay --kitti00 --robots 4 --every 2 --poses refined
    |   sgloc replay --city --robots 8 --backend robots
    """
    setting, online = split_online_settings(setting)
    inputs = _claim(ctx, sources or [], robot or [], classes, config, out, out_bag)
    job = replay_job(sources or [], robot or [], scenario_names(kitti00, city), robots=robots,
                     scans=scans, every=every, poses=poses, seed=seed, classes=classes,
                     odom_topic=odom_topic, objects_topic=objects_topic, backend=backend, root=root,
                     online=online)
    cfg = localizer_config(preset or job.preset, config, setting)
    with _bar(quiet) as progress:
        summary = job.run(cfg, out, out_bag, inputs, progress)
    _print(Console(quiet=quiet), summary, out, out_bag, len(job.logs))


def _claim(ctx: typer.Context, sources, robot, classes, config, out, out_bag) -> list:
    """Claim the outputs; returns the inputs they must not touch."""
    inputs = [*sources, *(r.partition("=")[2] for r in robot), classes, config]
    claim_output(ctx, out, inputs)
    if claim_output(ctx, out_bag, inputs, "--out-bag") is not None:
        require("rosbags", "ros", "--out-bag (a ROS 2 bag)")  # refused before the replay
    return inputs


def scenario_names(kitti00: bool, city: bool) -> list[str]:
    """The scenarios asked for, their makers loaded (`sgloc.evaluation.replay_scenarios` adds
    them to the replay's `REPLAY_SCENARIOS`)."""
    names = [name for name, on in (("kitti00", kitti00), ("city", city)) if on]
    if names:
        import sgloc.evaluation.replay_scenarios  # noqa: F401
    return names


def _bar(quiet: bool):
    columns = (TextColumn("[bold]replaying"), BarColumn(), MofNCompleteColumn(),
               TimeElapsedColumn())
    return progress_bar(*columns, console=Console(quiet=quiet), disable=quiet)


def _print(console: Console, summary: dict, out: Path, out_bag: Path | None, robots: int) -> None:
    """The replay's table and counts; exit 1 (not localized) when no robot joined another."""
    table = Table("robot", "keyframes", "joined at (s)", "placed", "latency median / p99 / max "
                  "(ms)", title="replay")
    for name, r in summary["robots"].items():
        lat = r["latency"]
        table.add_row(name, str(r["keyframes"]), r["joined_stamp"] or "-",
                      "yes" if r["placed"] else "NO",
                      f"{lat['median_ms']:.2f} / {lat['p99_ms']:.1f} / {lat['max_ms']:.1f}")
    console.print(table)
    for name, r in summary["robots"].items():
        if not r["placed"]:
            console.print(f"{name} not placed: {r['unplaced_reason']}.")
    ev = summary["events"]
    console.print(f"{summary['placed']} of {len(summary['robots'])} robots placed in the frame of "
                  f"{summary['root']}; {ev['link_accepted']} links accepted, "
                  f"{ev['link_revoked']} revoked -> {out}" + (f", {out_bag}" if out_bag else ""))
    if robots < 2:
        raise not_localized(f"the input holds one robot ({summary['root']}): a replay joins two "
                            "or more robots in one fleet frame.")
    if summary["placed"] < 2:
        raise not_localized(f"no robot joined the fleet frame of {summary['root']}.")
