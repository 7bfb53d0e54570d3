"""The evaluation's scene factory: one module order without cycles, one overlap definition, one
KITTI map builder shared by the trials, the acceptance pair sets and the fleet scenes."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import sgloc.evaluation
from sgloc.evaluation.scenes import move_target, pair_rng, route_overlap

#: The evaluation modules from the lowest up: each imports only modules before it.
ORDER = (
    "metrics", "scenes", "pairs_kitti", "kitti_refined", "pairs_sim", "pairs",
    "acceptance_pairs", "fleet_scenes", "replay_scenarios", "online_oracle", "fleet_trajectory",
    "online_replay", "fleet_metrics", "fleet_oracle", "fleet_runs", "fleet_cases", "trials",
    "report", "plots", "experiments",
)  # fmt: skip
PACKAGE = Path(sgloc.evaluation.__file__).parent


def _evaluation_imports(module: str) -> set[str]:
    tree = ast.parse((PACKAGE / f"{module}.py").read_text())
    out = set()
    prefix = "sgloc.evaluation."
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module == "sgloc.evaluation":
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith(prefix):
            out.add(node.module.split(".")[2])
        elif isinstance(node, ast.Import):
            out |= {a.name.split(".")[2] for a in node.names if a.name.startswith(prefix)}
    return out


def test_modules_import_only_lower_ones():
    assert set(ORDER) == {p.stem for p in PACKAGE.glob("*.py")} - {"__init__"}
    for k, module in enumerate(ORDER):
        higher = _evaluation_imports(module) - set(ORDER[:k])
        assert not higher, f"{module} imports {higher}"


@pytest.mark.parametrize("module", ["scenes", "pairs_kitti", "pairs", "acceptance_pairs"])
def test_each_module_imports_alone(module):
    code = f"import sgloc.evaluation.{module}"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_no_private_names_exported():
    for module in ORDER:
        mod = __import__(f"sgloc.evaluation.{module}", fromlist=["_"])
        assert not [n for n in getattr(mod, "__all__", []) if n.startswith("_")], module


def test_no_private_evaluation_name_is_used_outside_its_module():
    root = Path(__file__).resolve().parents[1]
    files = [*PACKAGE.glob("*.py"), *(root / "benchmarks").rglob("*.py"), *root.glob("tests/*.py")]
    for path in files:
        for node in ast.walk(ast.parse(path.read_text())):
            module = node.module or "" if isinstance(node, ast.ImportFrom) else ""
            if module.startswith("sgloc.evaluation"):
                private = [a.name for a in node.names if a.name.startswith("_")]
                assert not private, f"{path.name} imports {private} from {node.module}"


def test_route_overlap_is_the_shared_length_fraction():
    x = np.linspace(0.0, 100.0, 101)
    query = np.column_stack([x, np.zeros_like(x)])
    target = query[:51] + [0.0, 3.0]  # beside the first half, 3 m off
    # within 5 m of the target: x < 50 + 4 (3-4-5), i.e. the 54 one-metre steps from x = 0..53
    assert route_overlap(query, target, 5.0) == pytest.approx(0.54)
    assert route_overlap(query, target, 2.0) == 0.0
    assert route_overlap(query, query, 1.0) == pytest.approx(1.0)


def test_move_target_draws_the_pairs_motion_from_the_seed(rng):
    from sgloc.maps.graph import SemanticGraph

    g = SemanticGraph(rng.uniform(-50, 50, (20, 3)), rng.integers(0, 3, 20))
    a, b = move_target(g, g, np.eye(4), pair_rng(3)), move_target(g, g, np.eye(4), pair_rng(3))
    np.testing.assert_array_equal(a.T_target_query, b.T_target_query)
    np.testing.assert_allclose(a.target.positions, g.transformed(a.T_moved_own).positions)
    assert np.linalg.norm(a.T_moved_own[:3, 3]) <= 200.0


def test_synthia_extraction_preset_drops_the_datasets_stuff_classes():
    from sgloc.datasets.synthia import SYNTHIA_STUFF_CLASSES
    from sgloc.extraction import extraction_preset

    assert extraction_preset("synthia").ignore_classes == SYNTHIA_STUFF_CLASSES


@pytest.mark.data
def test_sliding_windows_use_route_overlap(data_dir):
    from sgloc.evaluation.pairs_kitti import Kitti00Pairs, kitti_sequence

    src = Kitti00Pairs().resolved()
    k = int(src.places()[0])
    a, starts, ovs = src.sliding_windows(k)
    xy = kitti_sequence(src.root)[0][:, [0, 2], 3]
    for c in np.linspace(0, len(starts) - 1, 7).astype(int):
        s = int(starts[c])
        direct = route_overlap(xy[s : s + src.length], xy[a[0] : a[1] + 1], src.radius)
        assert ovs[c] == pytest.approx(direct, abs=1e-9)


@pytest.mark.data
def test_trials_acceptance_pairs_and_fleets_share_the_kitti_map_builder(data_dir):
    from sgloc.evaluation.acceptance_pairs import kitti_pairs
    from sgloc.evaluation.fleet_scenes import kitti_fleet
    from sgloc.evaluation.pairs_kitti import kitti_graph, kitti_root

    root = kitti_root()
    (pos,) = kitti_pairs(1, positive=True, seed=0)
    a, b = pos.info["target_scans"], pos.info["query_scans"]
    assert pos.target is kitti_graph(root, *a) and pos.query is kitti_graph(root, *b)
    scene = kitti_fleet(((0, 300), (200, 500)))
    assert scene.graphs[0] is kitti_graph(root, 0, 300)
    one_scan = kitti_graph(root, 100, 100)  # every object seen once: none dropped for it
    assert len(one_scan) >= 3 and one_scan.name == "kitti00[100]"
