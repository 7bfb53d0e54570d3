"""`sgloc replay`: stream recorded multi-robot runs through an online session."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from sgloc.cli.app import app, fail, not_localized
from sgloc.cli.options import (
    class_table_option,
    config_option,
    localizer_config,
    preset_option,
    set_option,
)
from sgloc.cli.outputs import claim_output


@app.command("replay")
def replay_cmd(
    ctx: typer.Context,
    sources: list[Path] | None = typer.Argument(
        None, metavar="[SOURCE]...", help="A plain layout folder (one folder per robot: "
        "odometry.tum, objects.csv), a rosbag2 folder or an .mcap/.db3 file; or one bag (or "
        "robot folder) per robot, each robot named by its file's stem."
    ),
    robot: list[str] = typer.Option(
        [], "--robot", metavar="NAME=PATH", help="A robot's own bag (or robot folder), the "
        "robot named NAME (repeatable; with or instead of SOURCES)."
    ),
    kitti00: bool = typer.Option(False, "--kitti00", help="Replay KITTI 00 (data `kitti00`) "
                                 "cut into --robots consecutive segments."),
    city: bool = typer.Option(False, "--city", help="Replay the synthetic city's two routes cut "
                              "into --robots robots (objects only, no rendering)."),
    robots: int = typer.Option(4, min=1, help="Robots to cut --kitti00 / --city into."),
    scans: str = typer.Option("0-2999", help="KITTI 00 scans to cut (--kitti00), first-last."),
    every: int = typer.Option(1, min=1, help="Use every n-th scan as a keyframe (--kitti00)."),
    poses: str = typer.Option("raw", help="KITTI 00 poses used as the robots' odometry and as "
                              "the truth (--kitti00): raw (poses_00.txt) or refined (made "
                              "consistent with the refined revisit transforms; needs gtsam)."),
    seed: int = typer.Option(0, min=0, help="City (--city) and session seed."),
    out: Path = typer.Option(Path("results/replay"), help="Results folder: a new or empty "
                             "folder, or an earlier results folder of sgloc (replaced)."),
    out_bag: Path | None = typer.Option(None, help="Also write the fleet frames as "
                                        "geometry_msgs/TransformStamped into this ROS 2 bag "
                                        "folder: new, empty, or an earlier bag of sgloc "
                                        "(replaced)."),
    classes: Path | None = class_table_option(
        "for class names in objects.csv or marker namespaces", "--classes"
    ),
    odom_topic: str | None = typer.Option(None, help="Odometry topic template (default "
                                          "/{robot}/odom), or a plain topic name (/odom) for "
                                          "bags of one robot each."),
    objects_topic: str | None = typer.Option(None, help="Object topic template (default "
                                             "/{robot}/objects), or a plain topic name."),
    root: str | None = typer.Option(None, help="Robot whose odometry frame is the fleet frame "
                                    "(default: the first to send a keyframe)."),
    preset: str | None = preset_option(),
    config: Path | None = config_option(),
    setting: list[str] = set_option(),
    backend: str = typer.Option("robots", help="Fleet back-end: robots (one rigid frame per "
                                "robot) or keyframes (a pose graph over every keyframe, for "
                                "drifting odometry; docs/online_session.md)."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar or table."),
) -> None:
    """Stream every robot's keyframes, interleaved by stamp, through one online session and
    write the fleet: fleet/<robot>.tum, events.csv, links.g2o, summary.json, timeline.png,
    fleet.png.

    Examples: sgloc replay runs/campus --out results/campus --out-bag results/campus_bag
    |   sgloc replay alpha.mcap beta.mcap --odom-topic /odom --objects-topic /objects
    |   sgloc replay --kitti00 --robots 4 --every 2 --poses refined
    |   sgloc replay --city --robots 8 --backend keyframes
    """
    from sgloc.online import OnlineConfig, OnlineSession
    from sgloc.replay import replay_logs
    from sgloc.replay.outputs import write_replay

    inputs = [*(sources or []), *(r.partition("=")[2] for r in robot), classes, config]
    claim_output(ctx, out, inputs)
    claim_output(ctx, out_bag, inputs, "--out-bag")
    logs, default_preset = _inputs(sources or [], robot, kitti00, city, robots, scans, every,
                                   seed, classes, odom_topic, objects_topic, poses)
    if backend not in ("robots", "keyframes"):
        raise fail(f"--backend {backend!r}: choose robots or keyframes.")
    if root is not None and root not in {g.name for g in logs}:
        raise fail(f"--root {root!r} is not a robot of the input; robots: "
                   f"{', '.join(g.name for g in logs)}.")
    cfg = localizer_config(preset or default_preset, config, setting)
    session = OnlineSession(cfg, OnlineConfig(seed=seed, backend=backend), root=root)
    console = Console(quiet=quiet)
    with Progress(TextColumn("[bold]replaying"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), console=console, disable=quiet) as bar:
        task = bar.add_task("keyframes", total=sum(len(g) for g in logs))
        record = replay_logs(logs, session, progress=lambda n: bar.advance(task, n))
    summary = write_replay(out, logs, session, record, inputs)
    if out_bag is not None:
        from sgloc.io.rosbag import write_fleet_bag

        write_fleet_bag(out_bag, record.transforms + _final(logs, session))
    _print(console, summary, out, out_bag)
    if len(logs) > 1 and summary["placed"] < 2:
        raise not_localized(f"no robot joined the fleet frame of {summary['root']}.")


def _inputs(sources, named, kitti00, city, robots, scans, every, seed, classes, odom_topic,
            objects_topic, poses="raw"):
    """(robot logs, default localizer preset) of the chosen input."""
    from sgloc.evaluation import replay_scenarios as scenarios

    if bool(sources or named) + kitti00 + city != 1:
        raise fail("give exactly one input: a layout folder or bag (or one bag per robot), "
                   "--kitti00, or --city.")
    if poses not in ("raw", "refined"):
        raise fail(f"--poses {poses!r}: choose raw or refined.")
    if poses != "raw" and not kitti00:
        raise fail(f"--poses {poses}: only for --kitti00 (other inputs bring their own poses).")
    if kitti00:
        try:
            first, last = (int(v) for v in scans.split("-"))
        except ValueError:
            raise fail(f"--scans {scans!r}: give first-last, e.g. 0-2999.") from None
        return scenarios.kitti_scenario(robots, first, last, every, poses).logs, "kitti-objects"
    if city:
        return scenarios.city_scenario(robots, seed).logs, "city"
    return _recorded(sources, named, classes, odom_topic, objects_topic), None


def _recorded(sources, named, classes, odom_topic, objects_topic) -> list:
    """The robots of one source, or of one source per robot (`named`: NAME=PATH items)."""
    from sgloc.replay.inputs import read_logs, read_robot_sources

    if len(sources) == 1 and not named:
        return read_logs(sources[0], classes, odom_topic, objects_topic)
    pairs = [(None, Path(p)) for p in sources]
    for item in named:
        name, sep, path = item.partition("=")
        if not sep or not name.strip() or not path.strip():
            raise fail(f"--robot {item!r}: give NAME=PATH, e.g. --robot alpha=runs/alpha.mcap.")
        pairs.append((name.strip(), Path(path.strip())))
    return read_robot_sources(pairs, classes, odom_topic, objects_topic)


def _final(logs, session) -> list:
    """The fleet frame of every placed robot at the last stamp."""
    end = max(int(g.stamps_ns[-1]) for g in logs)
    out = []
    for g in logs:
        T = session.T_fleet_robot(g.name) if g.name in session.robots else None
        if T is not None:
            out.append((end, g.name, T))
    return out


def _print(console: Console, summary: dict, out: Path, out_bag: Path | None) -> None:
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
