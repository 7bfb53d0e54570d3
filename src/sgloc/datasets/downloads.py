"""Where data lives, and how to get it.

Data sets (`DOWNLOADS`): `airsim_guo` ships inside the package (Guo et al.'s two Airsim object
maps, MIT); `kitti00` (KITTI odometry 00 LiDAR objects, poses and refined loop transforms, CC
BY-NC-SA 3.0) is downloaded on demand by `sgloc data fetch kitti00` from its public repositories
at pinned commits, each file checked against its sha256.

A set named NAME is looked up in, first found wins:
1. `$SGLOC_DATA/NAME` when `SGLOC_DATA` is set (then nothing else but the shipped sample);
2. the per-user data folder (`user_data_dir()`, where `sgloc data fetch` puts it);
3. `../shared/data/NAME` beside a source checkout (for the developers);
4. the copy shipped inside the package (`airsim_guo` only).
Caches (rendered synthetic runs, extracted graphs) go to `cache_dir()`.
"""

from __future__ import annotations

import os
import shutil
import sys
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from sgloc.errors import DatasetError
from sgloc.maps.graph import DEFAULT_EDGE_RADIUS
from sgloc.registry import Registry

#: The source tree's root when running from a checkout (src/sgloc/datasets/downloads.py); after an
# install
#: this points into site-packages and `checkout_data_dir()` returns None.
PROJECT_ROOT = Path(__file__).resolve().parents[3]

#: Environment variables: the data folder, the cache folder, a mirror for `sgloc data fetch`
#: laid out like the data folder (`<url>/<set>/<file>`; used by the tests' local server).
ENV_DATA, ENV_CACHE, ENV_URL = "SGLOC_DATA", "SGLOC_CACHE", "SGLOC_DATA_URL"


@dataclass(frozen=True)
class RemoteFile:
    """One file of a data set: its name in the set's folder and where it is published."""

    name: str
    repo: str  # GitHub owner/name
    commit: str  # full commit id (pinned)
    path: str  # path inside the repository
    sha256: str  # of the file as kept in the data set's folder
    #: when the published file holds more than the set needs: its sha256, and the sequence
    #: whose rows (first column) are kept, with the header line
    upstream_sha256: str | None = None
    keep_sequence: str | None = None

    def source(self, dataset: str) -> tuple[str, str]:
        """(URL, expected sha256): the pinned raw GitHub file, or `$SGLOC_DATA_URL/<set>/<name>`
        (a mirror laid out like the data folder, serving the files as kept)."""
        base = os.environ.get(ENV_URL)
        if base:
            return f"{base.rstrip('/')}/{dataset}/{self.name}", self.sha256
        url = f"https://raw.githubusercontent.com/{self.repo}/{self.commit}/{self.path}"
        return url, self.upstream_sha256 or self.sha256


@dataclass(frozen=True)
class DataSet:
    """A named data set: what it is, its licence, its files, whether the package ships it."""

    name: str
    description: str
    licence: str
    files: tuple[RemoteFile, ...]
    shipped: bool = False
    licence_detail: str = ""
    size: str = ""  # on disk, for `sgloc data list`


_GUO = ("GuancongLuo/semantic-histogram-based-global-localization",
        "b0aa99964f0e791984a9f818f7c9083931962251")
_GOSMATCH = ("zhuyachen/GOSMatch", "200fcbf9e0c40083642e16ceef56f8dbf61e6903")
_EVO = ("MichaelGrupp/evo", "9ec1444a9f26a24261e1c126cd4ee2d7877cc395")
_G3REG = ("HKUST-Aerial-Robotics/G3Reg", "03c4b00661468d3ea0f762b634a2b21792b74613")
#: refined loop lists: (sha256 of the sequence-00 rows kept here, sha256 of G3Reg's file, which
#: holds every sequence)
_LC_HASH = {
    "0_10": ("9b37ff9ffba3954a491177dc031c3621577395cc33342bea986dc1d61624251d",
             "1540439ad4f31211f5e0f971870cc51d303e45fc47eb7c649411a22b29bca9b0"),
    "10_20": ("58a6fa7dbfd56276e7c171591b27d58d2392eb264e5fa1a54b4fdd2842faf321",
              "e40ee43a27f707eaa40dd0c0ad91648dbd203582d3190877eab897f5ff1dd34a"),
    "20_30": ("73478ef6aacf884be6244f0cf15792f75561a5687b3eb840b9e132352c175830",
              "2f9de9ca4283b3c033ffbd4eab074ad9f13d22c141ca0d8ee5d9cbf742de50ce"),
}

DOWNLOADS: Registry[DataSet] = Registry("data set", {
    "airsim_guo": DataSet(
        "airsim_guo",
        "Airsim object maps of two robots (Guo et al., RA-L 2021); shipped with sgloc",
        "MIT",
        (
            RemoteFile("cloud1.pcd", *_GUO, "results/cloud1.pcd",
                       "5f64ab4cdbf9cdf33c820efcb572ac6ce69f60d191f2b9978f373fed7a0fc7cb"),
            RemoteFile("cloud2.pcd", *_GUO, "results/cloud2.pcd",
                       "8e4f2067406464ebb1d0dfdfae310fe9b85216dbb318709e94747c00fc196365"),
        ),
        shipped=True,
        size="26 KB",
        licence_detail="MIT licence of gxytcrc/semantic-histogram-based-global-localization "
        "(Copyright (c) 2022 gxytcrc); the maps were written by that code.",
    ),
    "kitti00": DataSet(
        "kitti00",
        "KITTI odometry 00: GOSMatch LiDAR object centroids, ground-truth poses, "
        "refined loop-closure transforms",
        "CC BY-NC-SA 3.0",
        (
            RemoteFile("gosmatch_00_objects.tar.xz", *_GOSMATCH, "00.tar.xz",
                       "fb736417cdd1906ac7b43ad57780d84689b547767dff376ccde1262aaff15849"),
            RemoteFile("poses_00.txt", *_EVO, "test/data/KITTI_00_gt.txt",
                       "90791a4113df979b149fa9e1104e960ea59f525a8318a202dbb6aec1a3d88793"),
            *(
                RemoteFile(f"kitti_lc_test_{k}.txt", *_G3REG,
                           f"configs/datasets/kitti_lc/test_{k}.txt", h, up, keep_sequence="0")
                for k, (h, up) in _LC_HASH.items()
            ),
        ),
        size="3.5 MB",
        licence_detail="Derived from the KITTI Vision Benchmark (Geiger et al.), licensed CC "
        "BY-NC-SA 3.0: non-commercial use only, attribute, share alike "
        "(https://www.cvlibs.net/datasets/kitti/). Hosted by GOSMatch (objects), evo (poses) and "
        "G3Reg (refined loop transforms, sequence 00 rows kept), whose code is MIT.",
    ),
})


def dataset(name: str) -> DataSet:
    """The DataSet called `name` (`-` and `_` alike); UnknownNameError listing the names."""
    return DOWNLOADS.lookup(name)


def user_data_dir() -> Path:
    """The per-user data folder (`sgloc data fetch` writes here unless SGLOC_DATA is set)."""
    import platformdirs

    return Path(platformdirs.user_data_dir("sgloc", appauthor=False))


def cache_dir() -> Path:
    """The cache folder: `$SGLOC_CACHE`, else the per-user cache folder (~/.cache/sgloc)."""
    if os.environ.get(ENV_CACHE):
        return Path(os.environ[ENV_CACHE])
    import platformdirs

    return Path(platformdirs.user_cache_dir("sgloc", appauthor=False))


def checkout_data_dir() -> Path | None:
    """`../shared/data` beside a source checkout (the developers' copy); None once installed."""
    if (PROJECT_ROOT / "pyproject.toml").is_file() and Path(__file__).parents[2].name == "src":
        return PROJECT_ROOT.parent / "shared" / "data"
    return None


def data_roots() -> list[Path]:
    """The folders searched for data sets, in order (see the module docstring)."""
    if os.environ.get(ENV_DATA):
        return [Path(os.environ[ENV_DATA])]
    roots = [user_data_dir()]
    checkout = checkout_data_dir()
    return roots + ([checkout] if checkout is not None else [])


def fetch_dir() -> Path:
    """Where `sgloc data fetch` writes: `$SGLOC_DATA` when set, else `user_data_dir()`."""
    return Path(os.environ[ENV_DATA]) if os.environ.get(ENV_DATA) else user_data_dir()


def sample_dir(name: str = "airsim_guo") -> Path:
    """The folder of a data set shipped inside the package."""
    return Path(str(resources.files("sgloc") / "sample_data" / name))


def find_dataset(name: str) -> Path | None:
    """The folder holding data set `name`, or None when it is nowhere (see module docstring)."""
    ds = dataset(name)
    for root in data_roots():
        if (root / ds.name).is_dir():
            return root / ds.name
    return sample_dir(ds.name) if ds.shipped else None


def dataset_dir(name: str) -> Path:
    """The folder of data set `name`; DatasetError naming `sgloc data fetch NAME` if absent."""
    found = find_dataset(name)
    if found is None:
        ds = dataset(name)
        where = ", ".join(str(r) for r in data_roots())
        raise DatasetError(
            f"data set {ds.name!r} not found (looked in {where}); "
            f"run `sgloc data fetch {ds.name}` or set SGLOC_DATA to the folder holding {ds.name}/."
        )
    missing = [f.name for f in dataset(name).files if not (found / f.name).is_file()]
    if missing:  # e.g. left by a failed download
        raise DatasetError(
            f"data set {dataset(name).name!r} in {found} is incomplete (missing "
            f"{', '.join(missing)}); run `sgloc data fetch {dataset(name).name}`."
        )
    return found


def data_root(must_exist: bool = True) -> Path:
    """The first data folder that exists (or, when `must_exist` is False, the first searched)."""
    roots = data_roots()
    for root in roots:
        if root.is_dir():
            return root
    if must_exist:
        raise DatasetError(
            f"no data folder found (looked in {', '.join(map(str, roots))}); "
            "run `sgloc data fetch kitti00` or set SGLOC_DATA."
        )
    return roots[0]


def data_path(*parts: str) -> Path:
    """A path inside data set `parts[0]`, e.g. data_path("kitti00", "poses_00.txt")."""
    p = dataset_dir(parts[0]).joinpath(*parts[1:])
    if not p.exists():
        raise DatasetError(
            f"{p} not found; run `sgloc data fetch {dataset(parts[0]).name}` to (re)download it."
        )
    return p


def airsim_guo(edge_radius: float = DEFAULT_EDGE_RADIUS):
    """(cloud1, cloud2): Guo et al.'s Airsim object maps as SemanticGraphs (shipped with sgloc;
    both in one world frame, so the ground truth between them is the identity)."""
    from sgloc.maps.graph import SemanticGraph

    d = dataset_dir("airsim_guo")
    return tuple(SemanticGraph.load(d / f, edge_radius=edge_radius)
                 for f in ("cloud1.pcd", "cloud2.pcd"))


def airsim_guo_paths() -> tuple[Path, Path]:
    """Paths of the two Airsim maps (cloud1.pcd, cloud2.pcd) as found by `dataset_dir`."""
    d = dataset_dir("airsim_guo")
    return d / "cloud1.pcd", d / "cloud2.pcd"


def is_complete(name: str, folder: Path | None = None) -> bool:
    """Whether every file of data set `name` is in `folder` (default: where it is found)."""
    ds = dataset(name)
    folder = folder if folder is not None else find_dataset(name)
    return folder is not None and all((folder / f.name).is_file() for f in ds.files)


def present_or_say(name: str, part: str, required: bool = False) -> bool:
    """Whether data set `name` is complete; if not, say on stderr that `part` is left out and
    how to get the set (a benchmark runs the rest), or with `required` exit with that."""
    if is_complete(name):
        return True
    how = f"run `sgloc data fetch {name}` (or set SGLOC_DATA to the folder holding {name}/)"
    if required:
        raise SystemExit(f"error: data set {name} not found: {how}; it is needed here.")
    print(f"note: data set {name} not found, so {part} is left out; {how} to include it.",
          file=sys.stderr)  # fmt: skip
    return False


def verified_copy(name: str) -> Path | None:
    """The folder of a complete copy of data set `name` in one of `data_roots()` whose every
    file matches its pinned sha256 (not the copy shipped in the package), or None."""
    ds = dataset(name)
    for root in data_roots():
        folder = root / ds.name
        if all((folder / f.name).is_file() and _sha256(folder / f.name) == f.sha256
               for f in ds.files):  # fmt: skip
            return folder
    return None


def fetch(name: str, dest: Path | None = None, progress: bool = False) -> Path:
    """Download data set `name` into `dest/<name>` (default `fetch_dir()`), each file checked
    against its pinned sha256; files already there with the right hash are kept. Without
    `dest`, a verified copy already in a data folder is used as it is. Returns the set's
    folder. Raises DatasetError when a download fails or a hash does not match."""
    ds = dataset(name)
    if dest is None and (found := verified_copy(ds.name)) is not None:
        return found  # already in a data folder (e.g. beside a checkout): nothing to download
    folder = Path(dest if dest is not None else fetch_dir()) / ds.name
    created = not folder.exists()
    folder.mkdir(parents=True, exist_ok=True)
    try:
        _fetch_files(ds, folder, progress)
    except BaseException:
        for partial in folder.glob("*.download"):
            partial.unlink(missing_ok=True)
        if created:  # leave no folder that looks like a data set
            shutil.rmtree(folder, ignore_errors=True)
        raise
    return folder


def _fetch_files(ds: DataSet, folder: Path, progress: bool) -> None:
    """Download the files of `ds` missing from `folder` (or with another hash)."""
    for f in ds.files:
        target = folder / f.name
        if target.is_file() and _sha256(target) == f.sha256:
            continue
        url, expected = f.source(ds.name)
        got = _download(url, expected, folder, f.name + ".download", progress)
        if expected != f.sha256:  # the published file is a superset: keep one sequence
            _keep_sequence(got, f.keep_sequence or "", got)
            if _sha256(got) != f.sha256:
                got.unlink()
                raise DatasetError(f"{url}: the rows of sequence {f.keep_sequence} do not match "
                                   f"their pinned sha256 {f.sha256}.")
        got.replace(target)


def _download(url: str, sha256: str, folder: Path, fname: str, progress: bool) -> Path:
    """pooch.retrieve with the pinned hash; errors become one-line DatasetErrors."""
    import logging

    import pooch

    pooch.get_logger().setLevel(logging.WARNING)
    try:
        return Path(pooch.retrieve(url, known_hash=f"sha256:{sha256}", fname=fname,
                                   path=folder, progressbar=progress))
    except ValueError as e:  # pooch: hash mismatch
        raise DatasetError(f"{url}: the download does not match its pinned sha256 ({e}).") from e
    except Exception as e:  # noqa: BLE001  (network errors come in many types)
        raise DatasetError(
            f"cannot download {url} ({type(e).__name__}: {e}); check the connection or set "
            f"{ENV_URL} to a mirror."
        ) from e


def _keep_sequence(src: Path, sequence: str, dst: Path) -> None:
    lines = src.read_text().splitlines(keepends=True)
    kept = [ln for ln in lines[1:] if ln.split(maxsplit=1)[:1] == [sequence]]
    dst.write_text("".join(lines[:1] + kept))


def _sha256(path: Path) -> str:
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()
