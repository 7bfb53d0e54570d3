"""sgloc.prepare / PreparedMap: the same results as the graph it holds, exact incremental
growth, save/load, and the refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest
from references.descriptors import distance_histograms, histograms_at

import sgloc
from sgloc import Localizer, LocalizerConfig, PreparedMap, SemanticGraph, localize
from sgloc.datasets.downloads import airsim_guo
from sgloc.descriptors import DistanceHistogramDescriptor
from sgloc.matching.candidates import BLOCKS_MIN_OBJECTS
from sgloc.pipeline.prepared import PreparedMapError
from sgloc.sim.object_world import make_two_robot_scene


@pytest.fixture(scope="module")
def airsim() -> tuple[SemanticGraph, SemanticGraph]:
    return airsim_guo()


@pytest.fixture(scope="module")
def street() -> SemanticGraph:
    """A map larger than BLOCKS_MIN_OBJECTS objects (the matching kernel's prepared blocks)."""
    scene = make_two_robot_scene(seed=3, stretch=4000 / 0.47, view_radius=130.0)
    assert len(scene.target) > BLOCKS_MIN_OBJECTS
    return scene.target


def fresh(g: SemanticGraph) -> SemanticGraph:
    """The same map as a new graph object (no cached canonical form or descriptors)."""
    return SemanticGraph(g.positions, g.labels, g.edge_radius, g.name)


def assert_same(a, b) -> None:
    assert a.accepted == b.accepted and a.reason == b.reason
    assert (a.transform is None) == (b.transform is None)
    if a.transform is not None:
        assert np.array_equal(a.transform, b.transform)  # bit for bit
    for name in ("matches", "candidates", "survivors", "scores"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert a.confidence == b.confidence


def scans(g: SemanticGraph, rng: np.random.Generator, n: int, radius: float):
    """n query graphs: the objects within `radius` of random objects of g, moved rigidly."""
    out = []
    for c in rng.choice(len(g), n, replace=False):
        near = np.linalg.norm(g.positions - g.positions[c], axis=1) < radius
        yaw = rng.uniform(-np.pi, np.pi)
        R = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
        pos = g.positions[near] @ R.T + rng.normal(0, 0.2, (int(near.sum()), 3)) + [5, -3, 0]
        out.append(SemanticGraph(pos, g.labels[near], name=f"scan{c}"))
    return out


def test_prepared_equals_graph_airsim(path, airsim):
    q, t = airsim
    prepared = sgloc.prepare(t)
    queries = [q, *scans(q, np.random.default_rng(0), 3, 60.0)]
    for seed, query in enumerate(queries):
        a = localize(query, fresh(t), seed=seed)
        b = localize(query, prepared, seed=seed)
        assert_same(a, b)
    assert localize(q, prepared).accepted  # the two Airsim maps do localize


def test_prepared_equals_graph_large_map(path, street):
    prepared = Localizer().prepare(street)
    if path == "compiled":
        assert prepared.blocks is not None  # the matching kernel's prepared class blocks
    found = 0
    for seed, query in enumerate(scans(street, np.random.default_rng(1), 4, 60.0)):
        a = localize(query, fresh(street), seed=seed)
        b = localize(query, prepared, seed=seed)
        assert_same(a, b)
        found += a.accepted
    assert found >= 2


def test_query_with_a_class_the_map_lacks(airsim):
    q, t = airsim
    labels = q.labels.copy()
    labels[:10] = 1000  # a class the target has not
    query = SemanticGraph(q.positions, labels)
    assert_same(localize(query, fresh(t)), localize(query, sgloc.prepare(t)))


@pytest.mark.parametrize("descriptor", ["distance_histogram", "histogram"])
def test_add_equals_preparing_the_grown_map(path, airsim, descriptor):
    q, t = airsim
    config = LocalizerConfig(descriptor=descriptor)
    labels = t.labels.copy()
    labels[-4:] = 77  # the last batch brings a new class
    grown = SemanticGraph(t.positions, labels)
    prepared = sgloc.prepare(SemanticGraph(t.positions[:150], labels[:150]), config)
    prepared.add(t.positions[150:250], labels[150:250])
    assert prepared.add(np.zeros((0, 3)), np.zeros(0, int)) is prepared
    prepared.add(t.positions[250:], labels[250:])
    scratch = sgloc.prepare(grown, config)
    assert np.array_equal(prepared.graph.positions, grown.positions)
    assert np.array_equal(prepared.order, scratch.order)
    assert np.array_equal(prepared.classes, scratch.classes)
    assert np.array_equal(prepared.descriptors, scratch.descriptors)
    for seed in range(2):
        assert_same(localize(q, prepared, seed=seed, config=config),
                    localize(q, scratch, seed=seed, config=config))  # fmt: skip


def test_add_on_a_large_map(street):
    prepared = sgloc.prepare(SemanticGraph(street.positions[:-30], street.labels[:-30]))
    prepared.add(street.positions[-30:], street.labels[-30:])
    scratch = sgloc.prepare(street)
    assert np.array_equal(prepared.descriptors, scratch.descriptors)
    assert np.array_equal(prepared.blocks.blocks, scratch.blocks.blocks)


def test_prepared_map_keeps_the_chance_grid(street, tmp_path):
    """Preparing builds the acceptance test's neighbour grid at the config's radius; queries
    use that one (nothing over the whole map per query); add and load build the grown or
    loaded map's."""
    from sgloc.maps.neighbor_kernels import cell_grid

    prepared = sgloc.prepare(SemanticGraph(street.positions[:-30], street.labels[:-30]))
    cfg = prepared.config
    radius = float(cfg.acceptance.radius or cfg.ransac.threshold)
    grid = prepared.chance_grid
    assert grid is not None and len(grid.order) == len(street) - 30
    fresh = cell_grid(prepared.target.positions, prepared.target.labels, radius)
    for name in ("order", "sorted_keys", "xyz", "labels", "start"):
        assert np.array_equal(getattr(grid, name), getattr(fresh, name))
    for seed, query in enumerate(scans(street, np.random.default_rng(4), 2, 60.0)):
        localize(query, prepared, seed=seed)
        assert prepared.canonical.grid(radius) is grid  # the queries used the map's grid
    prepared.add(street.positions[-30:], street.labels[-30:])
    assert prepared.chance_grid is not grid and len(prepared.chance_grid.order) == len(street)
    loaded = PreparedMap.load(prepared.save(tmp_path / "map.npz"))
    assert loaded.chance_grid is not None and len(loaded.chance_grid.order) == len(street)


def test_save_load_round_trip(path, airsim, tmp_path):
    q, t = airsim
    prepared = sgloc.prepare(t, LocalizerConfig().with_overrides(descriptor_radius=35.0))
    file = prepared.save(tmp_path / "map.npz")
    loaded = PreparedMap.load(file)
    assert loaded.config.descriptor_config == prepared.config.descriptor_config
    assert np.array_equal(loaded.descriptors, prepared.descriptors)
    config = LocalizerConfig().with_overrides(descriptor_radius=35.0)
    for query in (q, *scans(q, np.random.default_rng(2), 2, 60.0)):
        a = localize(query, prepared, config=config)
        assert_same(a, localize(query, loaded, config=config))
    # The localizer's other settings are free; its descriptor is not.
    PreparedMap.load(file, config.with_overrides(ransac_threshold=3.0))
    with pytest.raises(PreparedMapError, match="radius: prepared 35.0, here 40.0"):
        PreparedMap.load(file, LocalizerConfig())
    with pytest.raises(PreparedMapError, match="radius: prepared 35.0, here 40.0"):
        localize(q, loaded)


def test_load_refuses_other_files(tmp_path, airsim):
    other = tmp_path / "graph.npz"
    airsim[1].save(other)
    with pytest.raises(PreparedMapError, match="not a prepared map"):
        PreparedMap.load(other)
    file = sgloc.prepare(airsim[1]).save(tmp_path / "map.npz")
    with np.load(file) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays.pop("meta")))
    meta["version"] = 99
    np.savez(tmp_path / "future.npz", meta=np.array(json.dumps(meta)), **arrays)
    with pytest.raises(PreparedMapError, match="version 99"):
        PreparedMap.load(tmp_path / "future.npz")
    meta["version"] = 1
    del meta["edge_radius"]
    np.savez(tmp_path / "broken.npz", meta=np.array(json.dumps(meta)), **arrays)
    with pytest.raises(PreparedMapError, match="edge_radius"):
        PreparedMap.load(tmp_path / "broken.npz")


def test_refusals(airsim):
    q, t = airsim
    with pytest.raises(PreparedMapError, match="random_walk"):
        sgloc.prepare(t, LocalizerConfig(descriptor="random_walk"))
    with pytest.raises(PreparedMapError, match="at least 3"):
        sgloc.prepare(SemanticGraph(t.positions[:2], t.labels[:2]))
    with pytest.raises(PreparedMapError, match="SemanticGraph"):
        sgloc.prepare(t.positions)
    with pytest.raises(PreparedMapError, match="n_bins: prepared 16, here 8"):
        localize(q, sgloc.prepare(t), descriptor_n_bins=8)


@pytest.mark.parametrize("n", [2, 3, 40, 700, 2500])
def test_distance_histogram_kernel_equals_reference(n):
    """The same bits by the grid kernel and by KD-tree pairs (weights on a 2**-24 grid: every
    bin's sum is exact in any order), duplicates and any subset of rows included."""
    rng = np.random.default_rng(n)
    pos = rng.uniform(-150, 150, (n, 3)) * [1, 1, 0.05]
    pos[n // 2 :: 7] = pos[0]  # duplicate objects
    labels = rng.integers(0, 6, n)
    d = DistanceHistogramDescriptor(radius=30.0, n_bins=12, taper=0.5)
    ref = distance_histograms(d, pos, labels, 6)
    got = d.rows(pos, labels, 6)
    assert ref.sum() > 0 and np.array_equal(got, ref)
    rows = rng.choice(n, min(n, 5), replace=False)
    assert np.array_equal(d.rows(pos, labels, 6, rows), ref[rows])
    assert np.array_equal(histograms_at(pos, np.arange(n), pos, labels, 6, 30.0, 12, 0.5), ref)


@pytest.mark.parametrize("n", [3, 300])
def test_histograms_at_other_centres_equal_reference(n):
    """Histograms at centres that are not the points (a grown map's update, `self_index` -1)
    or leave one point out: the kernel's bits equal the KD-tree reference's."""
    from sgloc.maps.neighbor_kernels import distance_histograms as kernel

    rng = np.random.default_rng(n)
    pts = rng.uniform(-60, 60, (n, 3)) * [1, 1, 0.05]
    labels = rng.integers(0, 5, n)
    centres = np.concatenate([rng.uniform(-60, 60, (40, 3)) * [1, 1, 0.05], pts[:2]])
    self_index = np.concatenate([np.full(40, -1), [0, 1]])
    args = (centres, self_index, pts, labels, 5, 25.0, 10, 0.3)
    ref = histograms_at(*args)
    assert ref.sum() > 0 and np.array_equal(kernel(*args), ref)


@pytest.mark.parametrize("n", [30, 400])
def test_distance_histogram_kernel_equals_reference_on_a_sparse_grid(n):
    """Clusters far apart (more grid cells than the table of runs holds: binary searches)
    give the reference's bits too."""
    rng = np.random.default_rng(n)
    pos = rng.uniform(-20, 20, (n, 3)) * [1, 1, 0.05]
    pos[::2] += [3e5, 2e5, 0.0]
    labels = rng.integers(0, 4, n)
    d = DistanceHistogramDescriptor(radius=15.0, n_bins=8, taper=0.8)
    ref = distance_histograms(d, pos, labels, 4)
    assert ref.sum() > 0 and np.array_equal(d.rows(pos, labels, 4), ref)
