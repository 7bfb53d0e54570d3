"""Small things a new user trips over: first-use compilation named in the times, skip reasons
shown, tests that keep out of the user's cache, pictures that show what they are about (real
stamps without an offset, overlapping paths, a small scan in a large map)."""

from __future__ import annotations

import dataclasses
import os
import re
import tempfile
from pathlib import Path

import numpy as np

from sgloc.cli import main
from sgloc.io.keyframes import make_robot_log
from sgloc.maps.graph import SemanticGraph
from sgloc.online import Event

ROOT = Path(__file__).resolve().parents[1]


def test_tests_cache_into_a_temporary_folder_and_show_skip_reasons():
    from sgloc.datasets.downloads import cache_dir

    assert Path(tempfile.gettempdir()) in cache_dir().parents
    assert os.environ["SGLOC_CACHE"] == str(cache_dir())
    text = (ROOT / "pyproject.toml").read_text()
    assert '-rs"' in text.split("addopts", 1)[1].splitlines()[0]


def test_the_stage_table_shows_first_use_compilation_apart(monkeypatch, capsys, tmp_path):
    """A kernel compiled inside a stage (a 2 s compile, simulated by numba's own compile event)
    is left out of that stage's time and of the total, and said on a line of its own."""
    import time
    import types

    from numba.core import event

    import sgloc.kernels
    import sgloc.pipeline.localizer as localizer

    sgloc.kernels.watch_compiles()
    (tmp_path / "compiled").touch()  # no first-use notice: this compile is only simulated
    monkeypatch.setattr(sgloc.kernels, "compiled_marker", lambda: tmp_path / "compiled")
    kernel = types.SimpleNamespace(__module__="sgloc.fake_kernels", __qualname__="fake")
    real_match = localizer.match_flagged

    def match_after_a_compile(*args):
        with event.trigger_event("numba:compile", data={"dispatcher": types.SimpleNamespace(
                py_func=kernel, __qualname__="fake")}):
            time.sleep(2.0)
        return real_match(*args)

    monkeypatch.setattr(localizer, "match_flagged", match_after_a_compile)
    assert main(["localize", "--example"]) == 0
    out = capsys.readouterr().out
    rows = {m[0]: float(m[1]) for m in re.findall(r"│ (\w+) +│ ([\d.]+) +│", out)}
    assert rows["matching"] < 1000 and rows["total"] < 1500, rows  # 2 s compiling not in them
    assert abs(sum(v for k, v in rows.items() if k != "total") - rows["total"]) < 0.1
    said = re.search(r"compiling the numba kernels on first use: ([\d.]+) s more, not in the "
                     r"times above", " ".join(out.split()))
    assert said and float(said[1]) >= 2.0, out
    monkeypatch.setattr(sgloc.kernels, "compile_seconds", lambda: (0.0, 0.0))
    assert main(["localize", "--example"]) == 0
    assert "compiling" not in capsys.readouterr().out


def _log(name: str, start_ns: int, n: int = 20):
    xyz = np.column_stack([np.arange(n) * 5.0, np.zeros(n), np.zeros(n)])
    return make_robot_log(name, start_ns + 500_000_000 * np.arange(n), xyz,
                          np.tile([0, 0, 0, 1.0], (n, 1)), [], np.zeros((0, 3)), [])


def test_the_timeline_shows_seconds_since_the_start_without_an_offset():
    from sgloc.replay.plots import timeline_figure

    logs = [_log("a", 1_700_000_000_000_000_000), _log("b", 1_700_000_002_000_000_000)]
    events = [Event(1_700_000_005.5, "robot_joined", ("b",))]
    fig = timeline_figure(logs, events)
    fig.canvas.draw()
    ax = fig.axes[0]
    assert ax.xaxis.get_offset_text().get_text() == ""
    assert "since the run's start" in ax.get_xlabel() and "1700000000.000000000" in ax.get_xlabel()
    lo, hi = ax.get_xlim()
    assert -2 < lo < 1 and 11 < hi < 14  # the run spans 0 .. 11.5 s
    marker = [ln for ln in ax.lines if ln.get_marker() == "o"][0]
    assert marker.get_xdata()[0] == 5.5


def _pixels_of(rgba: np.ndarray, colour) -> int:
    target = np.array(colour[:3]) * 255
    return int(np.count_nonzero(np.abs(rgba[..., :3].astype(float) - target).max(axis=-1) < 8))


def test_robots_on_the_same_path_stay_visible_in_the_fleet_picture():
    from sgloc.replay.plots import fleet_figure, robot_colours

    a = _log("a", 0)
    logs = [dataclasses.replace(a, name=f"r{k}") for k in range(5)]
    frames = {g.name: np.eye(4) for g in logs}
    fig = fleet_figure(logs, frames, {})
    fig.canvas.draw()
    rgba = np.asarray(fig.canvas.buffer_rgba())
    for c in robot_colours(5):  # each robot's own colour shows on the shared path
        assert _pixels_of(rgba, c) > 100  # a hidden path leaves only its legend entry (~20)


def test_a_small_scan_in_a_large_map_gets_a_zoomed_inset(tmp_path):
    from sgloc.io.pictures import plot_aligned_maps, scan_zoom

    rng = np.random.default_rng(0)
    big = rng.uniform(-1000, 1000, (400, 3))
    scan = rng.uniform(-10, 10, (15, 3)) + [300.0, -200.0, 0.0]
    box = scan_zoom(big, scan)
    assert box is not None and box[1] - box[0] < 60
    assert box[0] <= scan[:, 0].min() and scan[:, 0].max() <= box[1]
    assert box[2] <= scan[:, 1].min() and scan[:, 1].max() <= box[3]
    assert scan_zoom(big, rng.uniform(-800, 800, (50, 3))) is None
    t = SemanticGraph(big, rng.integers(0, 5, 400))
    q = SemanticGraph(scan, rng.integers(0, 5, 15))
    path = plot_aligned_maps(t, q, np.eye(4), np.zeros((0, 2)), tmp_path / "a.png", "small scan")
    assert path.stat().st_size > 0
