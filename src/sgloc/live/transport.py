"""Zenoh, imported lazily (extra `sgloc[live]`): sessions on explicit endpoints only (no
multicast scouting, nothing listening unless asked), and sgloc's key expressions."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from sgloc.errors import SglocError
from sgloc.optional import require

#: Where a server listens unless told otherwise: loopback only.
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
#: The first part of every sgloc key expression.
PREFIX = "sgloc"
_ENDPOINT = re.compile(r"^(tcp|udp|tls|quic)/(\[[0-9a-fA-F:.]+\]|[A-Za-z0-9_.-]+):\d{1,5}$")
_ROBOT = re.compile(r"^[A-Za-z0-9_-]{1,64}$")


def zenoh() -> Any:
    """The zenoh module, or a one-line error naming `pip install 'sgloc[live]'`."""
    return require("zenoh", "live", "the live server and robot clients")


def check_endpoint(endpoint: str, option: str = "--listen") -> str:
    """`endpoint` when it reads PROTOCOL/HOST:PORT (tcp/127.0.0.1:7447); SglocError otherwise."""
    if not isinstance(endpoint, str) or not _ENDPOINT.match(endpoint) \
            or not 0 < int(endpoint.rpartition(":")[2]) < 65536:
        raise SglocError(f"{option} {endpoint!r}: give PROTOCOL/HOST:PORT, e.g. "
                         f"{DEFAULT_ENDPOINT}.")
    return endpoint


def is_robot_name(robot: object) -> bool:
    """Whether `robot` is usable in a key expression: 1-64 of A-Z a-z 0-9 _ -."""
    return isinstance(robot, str) and _ROBOT.match(robot) is not None


def check_robot(robot: str) -> str:
    """`robot` when it is a robot name (`is_robot_name`); SglocError otherwise."""
    if not is_robot_name(robot):
        raise SglocError(f"robot name {robot!r}: use 1-64 letters, digits, '_' or '-'.")
    return robot


def key(robot: str, what: str, prefix: str = PREFIX) -> str:
    """The key expression of `robot`'s `what` (keyframe, correction)."""
    return f"{prefix}/{check_robot(robot)}/{what}"


def open_session(mode: str, listen: str | list[str] | None = None, connect: str | None = None,
                 config_file: str | Path | None = None) -> Any:
    """A zenoh session in `mode` ("router" for a server, "client" for a robot) listening on
    `listen` only (one endpoint or several) and connecting to `connect` only (no scouting);
    `config_file`: a Zenoh configuration file (JSON5) for everything else (TLS, access
    control, authentication)."""
    z = zenoh()
    conf = _config(z, config_file)
    conf.insert_json5("mode", f'"{mode}"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    listen = [listen] if isinstance(listen, str) else list(listen or [])
    conf.insert_json5("listen/endpoints",
                      "[" + ", ".join(f'"{check_endpoint(e)}"' for e in listen) + "]")
    if connect:
        conf.insert_json5("connect/endpoints", f'["{check_endpoint(connect, "--to")}"]')
    try:
        return z.open(conf)
    except Exception as e:  # zenoh raises its own ZError
        where = listen[0] if listen else connect
        why = str(e).split(" at /")[0][:120]
        raise SglocError(f"cannot open a zenoh session on {where}: {why} Is the port "
                         "free (server) or the server running (robot)?") from None


def _config(z: Any, config_file: str | Path | None) -> Any:
    if config_file is None:
        return z.Config()
    path = Path(config_file)
    if not path.is_file():
        raise SglocError(f"--zenoh-config {path}: no such file; give a Zenoh configuration "
                         "file (JSON5).")
    try:
        return z.Config.from_file(str(path))
    except Exception as e:  # zenoh raises its own ZError
        why = " ".join(str(e).split())[:160]
        raise SglocError(f"--zenoh-config {path}: not a valid Zenoh configuration ({why}); "
                         "see Zenoh's DEFAULT_CONFIG.json5 for the keys.") from None
