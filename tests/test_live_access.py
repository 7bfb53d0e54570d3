"""Who may publish to a live server: a Zenoh configuration file (`--zenoh-config`) with an
access-control rule keeps a robot out; a missing or invalid file is a one-line error."""

from __future__ import annotations

import socket
import subprocess
import sys
import time

import numpy as np
import pytest

pytest.importorskip("zenoh")

from sgloc.errors import SglocError  # noqa: E402
from sgloc.live.client import RobotClient  # noqa: E402
from sgloc.live.server import LiveServer, ServeOptions  # noqa: E402

DENY_MALLORY = """{
  access_control: {
    enabled: true,
    default_permission: "allow",
    rules: [{ id: "no-mallory", messages: ["put"], flows: ["ingress"], permission: "deny",
              key_exprs: ["sgloc/mallory/**"] }],
    subjects: [{ id: "loopback", interfaces: ["lo"] }],
    policies: [{ rules: ["no-mallory"], subjects: ["loopback"] }],
  },
}
"""


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _keyframe(client: RobotClient) -> int:
    pos = np.arange(9, dtype=float).reshape(3, 3)
    return client.send_keyframe(10**9, np.eye(4), pos, np.arange(3))


def test_an_access_rule_keeps_a_robot_out(tmp_path):
    conf = tmp_path / "base.json5"
    conf.write_text(DENY_MALLORY)
    ep = f"tcp/127.0.0.1:{_port()}"
    with LiveServer(options=ServeOptions(listen=ep, sync=True, zenoh_config=conf)) as srv:
        with RobotClient("alice", ep) as alice:
            assert alice.wait_correction(_keyframe(alice), timeout=10).placed
        with RobotClient("mallory", ep) as mallory:
            seq = _keyframe(mallory)
            with pytest.raises(SglocError, match="no correction"):
                mallory.wait_correction(seq, timeout=2)
        time.sleep(0.3)
        assert srv.session.robots == ["alice"] and srv.counts["received"] == 1


def test_without_the_file_the_same_robot_is_served():
    ep = f"tcp/127.0.0.1:{_port()}"
    with LiveServer(options=ServeOptions(listen=ep, sync=True)) as srv:
        with RobotClient("mallory", ep) as mallory:
            assert mallory.wait_correction(_keyframe(mallory), timeout=10).placed
        assert srv.session.robots == ["mallory"]


@pytest.mark.parametrize("content", [None, "{ mode: 12, listen: ["])
def test_a_missing_or_invalid_config_is_one_line(tmp_path, content):
    conf = tmp_path / "base.json5"
    if content is not None:
        conf.write_text(content)
    run = subprocess.run([sys.executable, "-m", "sgloc", "serve", "--listen",
                          f"tcp/127.0.0.1:{_port()}", "--zenoh-config", str(conf), "--seconds",
                          "1", "--quiet"], capture_output=True, text=True, timeout=120)
    assert run.returncode != 0
    err = run.stderr.strip().splitlines()
    assert len(err) == 1 and "--zenoh-config" in err[0] and str(conf) in err[0], run.stderr
    assert "Traceback" not in run.stderr
