"""The pair factory: `make_pair_source(name or folder, **params)` -> a pair source, a small
picklable object (a frozen dataclass of its parameters) with `__call__(seed) -> Pair`.

Sources register by name in `sgloc.evaluation.scenes.PAIR_SOURCES`: the file-based ones
(`graph-files`, `airsim-guo`, `synthia`) and the code-generated `object-world` here, `kitti00`
(pairs_kitti), `city` and `airsim-run` (pairs_sim). Everything random in a pair comes from the
seed, so a trial is a pure function of (source, parameters, seed) and gives the same pair on any
process or Dask worker. """

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from sgloc.errors import DatasetError, UnknownNameError
from sgloc.evaluation import pairs_kitti  # noqa: F401  (registers kitti00)
from sgloc.evaluation.pairs_sim import AirsimRunPairs  # (also registers city)
from sgloc.evaluation.scenes import (
    PAIR_SOURCES,
    MovedTargetSource,
    Pair,
    PairSource,
    extracted_graph,
    load_graph_cached,
    register_pair_source,
    route_overlap,
    window_overlaps,
)
from sgloc.geometry import invert
from sgloc.maps.graph import DEFAULT_EDGE_RADIUS, SemanticGraph

GRAPH_SUFFIXES = (".pcd", ".json", ".npz")


@register_pair_source("object-world")
@dataclass(frozen=True)
class ObjectWorldPairs:
    """The tiny code-generated object world (`sgloc.sim.object_world`): each seed draws a new
    world and two robots whose routes share `overlap` of their length."""

    overlap: float = 0.5
    stretch: float = 300.0
    view_radius: float = 40.0
    noise: float = 0.5

    def __call__(self, seed: int) -> Pair:
        from sgloc.sim.object_world import make_two_robot_scene

        scene = make_two_robot_scene(int(seed), **dataclasses.asdict(self))
        return Pair(scene.query, scene.target, scene.T_target_query, {"overlap": self.overlap})


@register_pair_source("graph-files")
@dataclass(frozen=True)
class GraphFilePairs(MovedTargetSource):
    """Two graph files in a folder (query and target; `.pcd`, `.json` or `.npz`), the target
    moved by a random rigid transform per trial. The maps' own relative pose is the identity,
    or the 4x4 matrix in `T_target_query.txt` in the same folder (p_target = T p_query)."""

    root: str | None = "."
    query_file: str | None = None
    target_file: str | None = None
    edge_radius: float = DEFAULT_EDGE_RADIUS

    def files(self) -> tuple[Path, Path]:
        root = Path(self.root)
        if self.query_file and self.target_file:
            q, t = root / self.query_file, root / self.target_file
        else:
            found = sorted(p for p in root.iterdir() if p.suffix.lower() in GRAPH_SUFFIXES)
            named = {p.stem.lower(): p for p in found}
            if "query" in named and "target" in named:
                q, t = named["query"], named["target"]
            elif len(found) == 2:
                q, t = found
            else:
                raise DatasetError(
                    f"{root}: expected two graph files (query.* and target.*, or exactly two "
                    f"{'/'.join(GRAPH_SUFFIXES)} files), found {len(found)}."
                )
        return q, t  # a missing file: SemanticGraph.load names it

    def maps(self, seed: int) -> tuple[SemanticGraph, SemanticGraph, np.ndarray, dict[str, Any]]:
        q, t = (load_graph_cached(str(p.resolve()), self.edge_radius) for p in self.files())
        gt_file = Path(self.root) / "T_target_query.txt"
        T0 = np.loadtxt(gt_file).reshape(4, 4) if gt_file.is_file() else np.eye(4)
        return q, t, T0, {}


@register_pair_source("airsim-guo")
@dataclass(frozen=True)
class AirsimGuoPairs(GraphFilePairs):
    """Guo's Airsim object maps: cloud1 (query) against cloud2 moved by a random rigid transform
    (any yaw, roll/pitch up to `max_roll_pitch_deg`, translation up to `max_translation` m).
    Both maps are in the Airsim world frame, so the ground truth is that transform; root: their
    folder (default: the `airsim_guo` data set under SGLOC_DATA)."""

    data_set: ClassVar[str | None] = "airsim_guo"
    root: str | None = None
    query_file: str | None = "cloud1.pcd"
    target_file: str | None = "cloud2.pcd"


# -- SYNTHIA: the forward (Omni_F) and backward (Omni_B) cameras as two robots ---------------
CAMERAS = ("Omni_F", "Omni_B")


@functools.lru_cache(maxsize=4)
def _camera_poses(root: str, camera: str) -> np.ndarray:
    """(N,4,4) world-from-optical poses of every frame of one camera."""
    from sgloc.datasets import make_dataset

    return make_dataset("synthia", root, camera=camera).poses


@register_pair_source("synthia")
@dataclass(frozen=True)
class SynthiaPairs(MovedTargetSource):
    """A SYNTHIA sequence folder (e.g. SYNTHIA-SEQS-04-SUMMER, or one written by
    `sgloc.sim.synthia_writer`): robot A (target) = Omni_F, robot B (query) = Omni_B, each map in
    its first frame's camera frame; the target is moved by a random rigid transform per trial.

    overlap=None: the whole sequences (Table 2). overlap=o: robot A maps the first `length`
    frames, robot B a window of `length` frames slid along the sequence so that the fraction of
    B's route within `radius` m of A's route is as close to o as it allows (the achieved value
    is in the pair's info as `overlap`). Ground truth: both cameras' poses are in the
    sequence's world frame, T_A_B = inv(P_A[a0]) @ P_B[b0].
    """

    data_set: ClassVar[str | None] = "synthia"
    root: str | None = None
    overlap: float | None = None
    length: int = 200
    radius: float = 10.0
    edge_radius: float = DEFAULT_EDGE_RADIUS

    def windows(self) -> tuple[tuple[int, int], tuple[int, int], float]:
        """(A frames, B frames, achieved route overlap), inclusive ranges."""
        PA, PB = (_camera_poses(self.root, c) for c in CAMERAS)
        xa, xb = PA[:, :3, 3], PB[:, :3, 3]
        if self.overlap is None:
            a, b = (0, len(PA) - 1), (0, len(PB) - 1)
            return a, b, route_overlap(xb, xa, self.radius)
        n = min(self.length, len(PA), len(PB))
        ovs = window_overlaps(xb, xa[:n], np.arange(len(PB) - n + 1), n, self.radius)
        s = int(np.argmin(np.abs(ovs - self.overlap)))
        return (0, n - 1), (s, s + n - 1), float(ovs[s])

    def maps(self, seed: int) -> tuple[SemanticGraph, SemanticGraph, np.ndarray, dict[str, Any]]:
        a, b, ov = self.windows()
        PA, PB = (_camera_poses(self.root, c) for c in CAMERAS)

        def graph(camera: str, w: tuple[int, int]) -> SemanticGraph:
            sel = {"camera": camera, "frames": w, "start_frame": True}
            name = f"{camera}[{w[0]}-{w[1]}]"
            return extracted_graph("synthia", self.root, name, self.edge_radius, **sel)

        target, query = graph(CAMERAS[0], a), graph(CAMERAS[1], b)
        info = {"overlap": round(ov, 4), "frames_a": f"{a[0]}-{a[1]}", "frames_b": f"{b[0]}-{b[1]}"}
        return query, target, invert(PA[a[0]]) @ PB[b[0]], info


def make_pair_source(name: str, **params: Any) -> PairSource:
    """A pair source by registered name (or alias), or by a folder: a SYNTHIA sequence (with
    CameraParams/), an Airsim-layout two-robot run (with ground_truth.txt), or a folder holding
    two graph files."""
    cls = PAIR_SOURCES.find(name)
    if cls is None:
        path = Path(name)
        if not path.is_dir():
            raise UnknownNameError(
                PAIR_SOURCES.unknown_message(
                    name,
                    "a folder holding two graph files or an Airsim-layout run with "
                    "ground_truth.txt",
                )
            )
        if (path / "CameraParams").is_dir():
            cls = SynthiaPairs
        else:
            cls = AirsimRunPairs if (path / "ground_truth.txt").is_file() else GraphFilePairs
        params = {"root": name, **params}
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = set(params) - known
    if unknown:
        raise UnknownNameError(
            f"dataset {name!r} has no parameter(s) {', '.join(sorted(unknown))}; "
            f"it takes {', '.join(sorted(known))}."
        )
    src = cls(**params)
    return src.resolved() if hasattr(src, "resolved") else src
