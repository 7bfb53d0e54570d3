"""`sgloc serve` and `sgloc stream`: a live base station over Zenoh, and a recorded run
played to it."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from sgloc.cli.app import app
from sgloc.cli.options import ConfigFile, Preset, Settings, file_path, localizer_config
from sgloc.cli.replay_cmd import (
    Backend,
    City,
    Classes,
    Every,
    Kitti00,
    ObjectsTopic,
    OdomTopic,
    Poses,
    Robot,
    Robots,
    Root,
    Scans,
    Seed,
    Sources,
    scenario_names,
)

Listen = Annotated[str, typer.Option(help="Zenoh endpoint to listen on (loopback by default; "
                                     "e.g. tcp/0.0.0.0:7447 for every interface).")]
State = Annotated[Path | None, typer.Option(
    parser=file_path, metavar="<path>", help="State file (.npz): saved atomically every "
    "--save-every seconds and on stop, resumed from when it exists.")]
SaveEvery = Annotated[float, typer.Option(min=0.1, help="Seconds between state saves.")]
Sync = Annotated[bool, typer.Option("--sync", help="Attempts inline after each keyframe, as "
                                    "`sgloc replay` runs them (no worker processes).")]
Workers = Annotated[int, typer.Option(min=1, help="Worker processes for attempts.")]
Scheduler = Annotated[str | None, typer.Option(help="Dask scheduler address for attempts "
                                               "(tcp://host:8786) instead of local workers.")]
MaxAttempts = Annotated[int, typer.Option(min=1, help="Attempts per scheduled batch.")]
Seconds = Annotated[float | None, typer.Option(min=0.0, help="Stop after this many seconds "
                                               "(default: run until Ctrl-C).")]
Quiet = Annotated[bool, typer.Option("--quiet", help="No status lines.")]
View = Annotated[bool, typer.Option("--view", help="Also serve the live view to Foxglove: open "
                                    "ws://127.0.0.1:8765 in the Foxglove app (docs/live.md).")]
ViewHost = Annotated[str, typer.Option(help="Address the live view listens on (loopback by "
                                       "default; 0.0.0.0 for every interface).")]
ViewPort = Annotated[int, typer.Option(min=0, max=65535, help="Port of the live view "
                                       "(0: any free port, printed).")]
To = Annotated[str, typer.Option(help="The server's Zenoh endpoint.")]
ZenohConfig = Annotated[Path | None, typer.Option(help="A Zenoh configuration file (JSON5) for "
                                                  "TLS, access control or authentication "
                                                  "(docs/live.md, \"Who may connect\").")]
Rate = Annotated[float, typer.Option(min=0.0, help="Speed-up over the recorded stamps (1: real "
                                     "time, 0: as fast as possible).")]
Ros2Domain = Annotated[int | None, typer.Option(min=0, max=232, help="ROS 2 domain "
                                               "(ROS_DOMAIN_ID) of ROS 2 robots and of the /tf, "
                                               "path and map outputs (rmw_zenoh keys; default 0 "
                                               "when the ROS 2 message types are installed; "
                                               "docs/live_ros2.md).")]
NoRos2 = Annotated[bool, typer.Option("--no-ros2", help="No ROS 2 robots or outputs.")]
Ros2Odom = Annotated[str, typer.Option(help="ROS 2 robots' odometry topic template.")]
Ros2Objects = Annotated[str, typer.Option(help="ROS 2 robots' object (MarkerArray) topic "
                                          "template.")]
As = Annotated[str, typer.Option("--as", help="sgloc: sgloc's own messages; ros2: as ROS 2 "
                                 "robots with rmw_zenoh (Odometry and MarkerArray in CDR).")]
Lockstep = Annotated[bool, typer.Option("--lockstep", help="Wait for each keyframe's correction "
                                        "before the next (with `serve --sync`: the replay's "
                                        "fleet exactly).")]


@app.command("serve")
def serve_cmd(
    listen: Listen = "tcp/127.0.0.1:7447",
    state: State = None,
    save_every: SaveEvery = 30.0,
    sync: Sync = False,
    workers: Workers = 1,
    scheduler: Scheduler = None,
    max_attempts: MaxAttempts = 2,
    backend: Backend = "keyframes",
    root: Root = None,
    seed: Seed = 0,
    preset: Preset = None,
    config: ConfigFile = None,
    setting: Settings = None,
    seconds: Seconds = None,
    view: View = False,
    view_host: ViewHost = "127.0.0.1",
    view_port: ViewPort = 8765,
    zenoh_config: ZenohConfig = None,
    ros2_domain: Ros2Domain = None,
    no_ros2: NoRos2 = False,
    odom_topic: Ros2Odom = "/{robot}/odom",
    objects_topic: Ros2Objects = "/{robot}/objects",
    classes: Classes = None,
    quiet: Quiet = False,
) -> None:
    """Host one online session for robots streaming over Zenoh: keyframes on
    sgloc/<robot>/keyframe, each robot's correction (map -> odom) on sgloc/<robot>/correction,
    events on sgloc/events (docs/live.md). ROS 2 robots with rmw_zenoh publish Odometry and
MarkerArray on /<robot>/odom and /<robot>/objects and get map -> <robot>/odom on /tf.

    Examples: sgloc serve --state base.npz   |   sgloc serve --preset city-objects --sync
    |   sgloc serve --listen tcp/0.0.0.0:7447 --workers 2   |   sgloc serve --view
    """
    from sgloc.io.class_table import read_class_table
    from sgloc.live.server import ServeOptions, serve
    from sgloc.online import OnlineConfig
    from sgloc.online.backend import BACKENDS

    if backend not in BACKENDS:
        raise typer.BadParameter(f"--backend {backend!r}: choose {' or '.join(BACKENDS)}.")
    console = Console(quiet=quiet)
    options = ServeOptions(
        listen, state, save_every, sync, workers, scheduler, max_attempts,
        view=view, view_host=view_host, view_port=view_port, zenoh_config=zenoh_config,
        ros2_domain=None if no_ros2 else ("auto" if ros2_domain is None else ros2_domain),
        odom_topic=odom_topic, objects_topic=objects_topic,
        classes=None if classes is None else read_class_table(classes))
    online = OnlineConfig(seed=seed, backend=backend)
    server = serve(localizer_config(preset, config, setting), online, options, seconds,
                   lambda s: console.print(_status(s)), root)
    console.print(_status(server))


def _status(server) -> str:
    s, c, o = server.session, server.counts, server.options
    where = f"serving on {o.listen} ({'sync' if o.sync else 'async'})"
    if server.view is not None:
        where += f", live view on {server.view.url}"
    drops = ", ".join(f"{k} {c[k]}" for k in sorted(c) if k not in ("received", "keyframes"))
    return (f"{where}: {len(s.robots)} robots ({len(s.corrections())} placed), {c['keyframes']} "
            f"keyframes, {sum(lk.active for lk in s.links)} active links; dropped: "
            f"{drops or 'none'}")


@app.command("stream")
def stream_cmd(
    sources: Sources = None,
    robot: Robot = None,
    kitti00: Kitti00 = False,
    city: City = False,
    robots: Robots = 4,
    scans: Scans = "0-2999",
    every: Every = 1,
    poses: Poses = "raw",
    seed: Seed = 0,
    classes: Classes = None,
    odom_topic: OdomTopic = None,
    objects_topic: ObjectsTopic = None,
    to: To = "tcp/127.0.0.1:7447",
    rate: Rate = 1.0,
    lockstep: Lockstep = False,
    zenoh_config: ZenohConfig = None,
    as_: As = "sgloc",
    ros2_domain: Annotated[int, typer.Option(min=0, max=232, help="ROS 2 domain with --as "
                                             "ros2.")] = 0,
    quiet: Quiet = False,
) -> None:
    """Play a recorded run (as `sgloc replay` reads it) to a server, one Zenoh session per
    robot, keyframes interleaved by stamp.

    Examples: sgloc stream --city --robots 4 --rate 2   |   sgloc stream runs/campus --to
    tcp/10.0.0.5:7447   |   sgloc stream --city --lockstep --rate 0   |   sgloc stream --city
    --as ros2
    """
    import numpy as np

    from sgloc.live.stream import stream_logs
    from sgloc.replay.job import replay_job

    if as_ not in ("sgloc", "ros2"):
        raise typer.BadParameter(f"--as {as_!r}: choose sgloc or ros2.")
    job = replay_job(sources or [], robot or [], scenario_names(kitti00, city), robots=robots,
                     scans=scans, every=every, poses=poses, seed=seed, classes=classes,
                     odom_topic=odom_topic, objects_topic=objects_topic)
    rec = stream_logs(job.logs, to, rate, lockstep, zenoh_config=zenoh_config,
                      ros2_domain=ros2_domain if as_ == "ros2" else None)
    lat = np.concatenate([np.asarray(v, float) for v in rec.latency_ms.values()] or [[]])
    placed = sum(c.placed for c in rec.corrections.values())
    Console(quiet=quiet).print(
        f"{rec.sent} keyframes of {len(job.logs)} robots sent to {to}; {placed} placed; "
        + (f"latency median {np.median(lat):.1f} ms, p99 {np.percentile(lat, 99):.1f} ms"
           if len(lat) else "no correction timed"))
