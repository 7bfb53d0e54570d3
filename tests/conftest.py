"""Shared fixtures. Real-data tests read $SGLOC_DATA (default ../shared/data); in CI it is there,
so they must run, not skip."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc import SemanticGraph
from sgloc.data import data_root


@pytest.fixture(scope="session")
def data_dir():
    return data_root()


@pytest.fixture(scope="session")
def airsim_graphs(data_dir) -> tuple[SemanticGraph, SemanticGraph]:
    """(cloud1, cloud2) of Guo's Airsim maps; ground truth between them is the identity."""
    d = data_dir / "airsim_guo"
    return SemanticGraph.load(d / "cloud1.pcd"), SemanticGraph.load(d / "cloud2.pcd")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)
