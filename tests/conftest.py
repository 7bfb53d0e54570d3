"""Shared fixtures and the `data` marker.

Guo's Airsim maps ship with the package, so tests using them always run. Tests needing the
downloaded KITTI 00 set carry the `data` marker (added here to every test using the `data_dir`
or `kitti_dir` fixture) and skip, naming `sgloc data fetch kitti00`, when it is absent. With
`SGLOC_REQUIRE_DATA=1` (as in CI, where the data is always there) such a test fails instead.
Every run caches into a temporary folder ($SGLOC_CACHE set here), never the user's."""

from __future__ import annotations

import importlib.util
import os
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from sgloc import SemanticGraph
from sgloc.datasets.downloads import ENV_CACHE, airsim_guo, dataset, dataset_dir, is_complete

#: Fixtures that need a downloaded data set; tests using them get the `data` marker.
DATA_FIXTURES = {"data_dir", "kitti_dir"}
#: The benchmark scripts some tests exercise.
BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def _load_benchmark(name: str, module_name: str | None = None) -> ModuleType:
    """benchmarks/<name>.py as a module, registered in sys.modules as `module_name` (default
    `name`), loaded once; no change to sys.path."""
    module_name = module_name or name
    if module_name not in sys.modules:
        spec = importlib.util.spec_from_file_location(module_name, BENCHMARKS / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[module_name] = module
        spec.loader.exec_module(module)
    return sys.modules[module_name]


@pytest.fixture(scope="session")
def benchmark_module() -> Callable[..., ModuleType]:
    """The loader of a benchmark script: `benchmark_module("fuzz")`."""
    return _load_benchmark


#: The temporary cache folder of this test run (`pytest_configure`).
_CACHE: list[Path] = []


def pytest_configure(config: pytest.Config) -> None:
    # Caches (rendered synthetic runs, extracted graphs) go to a temporary folder removed at the
    # end, never into the user's cache folder; subprocesses (the docs' commands) inherit it.
    import tempfile

    _CACHE.append(Path(tempfile.mkdtemp(prefix="sgloc-test-cache-")))
    os.environ[ENV_CACHE] = str(_CACHE[0])
    config.addinivalue_line(
        "markers",
        "data(name='kitti00'): needs a downloaded data set (`sgloc data fetch NAME`); skips when "
        "it is absent, fails then if SGLOC_REQUIRE_DATA is set",
    )


def pytest_unconfigure(config: pytest.Config) -> None:
    import shutil

    for folder in _CACHE:
        shutil.rmtree(folder, ignore_errors=True)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if DATA_FIXTURES & set(getattr(item, "fixturenames", ())):
            if item.get_closest_marker("data") is None:
                item.add_marker(pytest.mark.data)


def require_data(name: str = "kitti00") -> Path:
    """The folder of data set `name`; skips (or fails under SGLOC_REQUIRE_DATA) when absent."""
    if is_complete(name):
        return dataset_dir(name)
    msg = (
        f"data set {dataset(name).name} not found: run `sgloc data fetch {dataset(name).name}` "
        "or set SGLOC_DATA"
    )
    if os.environ.get("SGLOC_REQUIRE_DATA", "") not in ("", "0"):
        pytest.fail(f"{msg} (SGLOC_REQUIRE_DATA is set: data tests must run)", pytrace=False)
    pytest.skip(msg)


def pytest_runtest_setup(item: pytest.Item) -> None:
    marker = item.get_closest_marker("data")
    if marker is not None:
        require_data(*marker.args, **marker.kwargs)


@pytest.fixture(scope="session")
def kitti_dir() -> Path:
    """The KITTI 00 folder (gosmatch_00_objects.tar.xz, poses_00.txt, kitti_lc_test_*.txt)."""
    return require_data("kitti00")


@pytest.fixture(scope="session")
def data_dir(kitti_dir) -> Path:
    """The data folder holding kitti00/."""
    return kitti_dir.parent


@pytest.fixture(scope="session")
def airsim_dir() -> Path:
    """The folder of Guo's Airsim maps (shipped with the package unless SGLOC_DATA has them)."""
    return dataset_dir("airsim_guo")


@pytest.fixture(scope="session")
def airsim_graphs() -> tuple[SemanticGraph, SemanticGraph]:
    """(cloud1, cloud2) of Guo's Airsim maps; ground truth between them is the identity."""
    return airsim_guo()


@pytest.fixture(params=["compiled", "reference"])
def path(request):
    """Run a test on the compiled kernels and on the numpy references (tests/references)."""
    from references.paths import on_references

    if request.param == "compiled":
        yield request.param
        return
    with on_references():
        yield request.param


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def live_city():
    """The city cut into 4 robots, its preset, and the replay's session on it (the live
    tests' reference: read it, never change it)."""
    from sgloc.evaluation.replay_scenarios import city_scenario
    from sgloc.online import OnlineConfig, OnlineSession
    from sgloc.pipeline.presets import localizer_preset
    from sgloc.replay.stream import replay_logs

    logs = city_scenario(4, 0).logs
    config = localizer_preset("city-objects")
    ref = OnlineSession(config, OnlineConfig())
    replay_logs(logs, ref)
    assert len(ref.corrections()) == 4  # every robot placed: a fleet worth comparing
    return logs, config, ref
