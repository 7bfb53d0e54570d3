"""Save and resume an OnlineSession: one .npz holding the robots' map arrays and a JSON
document with everything else. A loaded file is checked by the rules `add_keyframe` and
`add_link` apply (`sgloc.io.keyframe_checks`) before a session is built from it."""

from __future__ import annotations

import json
import struct
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from sgloc.errors import SglocError
from sgloc.io.keyframe_checks import check_increasing, check_link, check_rigid, check_stamp
from sgloc.validation import check_graph_arrays

FORMAT = "sgloc-online-session-1"


class SessionFileError(SglocError):
    """A saved online session that cannot be read or holds what a session cannot."""


def save_session(session, path: str | Path) -> Path:
    """Write `session` (`OnlineSession.to_state`) to `path` (.npz appended when missing)."""
    p = Path(path)
    if p.suffix != ".npz":
        p = p.with_name(p.name + ".npz")
    p.parent.mkdir(parents=True, exist_ok=True)
    meta, arrays = session.to_state()
    np.savez_compressed(p, meta=np.array(json.dumps({"format": FORMAT, **meta})), **arrays)
    return p


def load_session(cls, path: str | Path):
    """The session saved at `path` (`cls.from_state`); SessionFileError naming the file when
    it is not a complete, valid saved session."""
    p = Path(path)
    try:
        with np.load(p, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files if k != "meta"}
            meta = json.loads(str(z["meta"]))
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error,
            struct.error, NotImplementedError, RuntimeError, OverflowError) as e:
        # A damaged archive: zipfile raises NotImplementedError for a mangled compression
        # method, RuntimeError for a flipped "encrypted" flag, struct.error for a short header.
        raise SessionFileError(
            f"{p}: not a saved online session, or a truncated one ({type(e).__name__}: "
            f"{str(e)[:80]}); give a file written by OnlineSession.save."
        ) from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        got = meta.get("format") if isinstance(meta, dict) else None
        raise SessionFileError(f"{p}: unknown session format {got!r} (need {FORMAT}).")
    try:
        check_state(meta, arrays)
        return cls.from_state(meta, arrays)
    except SglocError as e:
        raise SessionFileError(f"{p}: a damaged online session: {e}") from None
    except (KeyError, TypeError, ValueError, IndexError, AttributeError) as e:
        raise SessionFileError(
            f"{p}: a damaged online session ({type(e).__name__}: {str(e)[:80]}); save it again "
            "with OnlineSession.save."
        ) from None


def _pairs(meta: dict, key: str, n: int, width: int, ordered: bool = False) -> None:
    """meta[key]: rows [i, j, value...] with robot indices 0 <= i, j < n (`ordered`: i < j;
    otherwise i == j is a robot's own loop closures) and `width` ints."""
    for row in meta.get(key, []):
        if (not isinstance(row, list) or len(row) != 2 + width
                or not all(isinstance(v, int) and not isinstance(v, bool) for v in row)
                or not (0 <= row[0] < row[1] < n if ordered else 0 <= min(row[:2]) <= max(
                    row[:2]) < n) or min(row[2:], default=0) < 0):
            rule = f"0 <= i < j < {n}" if ordered else f"0 <= i, j < {n}"
            raise SglocError(f"{key!r} entry {row!r:.60} is not [robot i, robot j, counts] with "
                             f"{rule}.")


def check_state(meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
    """Refuse a session state (`OnlineSession.to_state`) that add_keyframe / add_link could not
    have made: robots that are not unique names, a robot's arrays missing or inconsistent,
    stamps that do not increase, poses or links that are not rigid, robot indices out of
    range."""
    robots = meta["robots"]
    if (not isinstance(robots, list) or not all(isinstance(r, str) and r for r in robots)
            or len(set(robots)) != len(robots)):
        raise SglocError("'robots' must be a list of distinct robot names.")
    n = len(robots)
    if meta.get("root") is not None and not isinstance(meta["root"], str):
        raise SglocError(f"'root' {meta['root']!r:.40} must be a robot name or null.")
    for k, r in enumerate(robots):
        where = f"robot {r!r}"
        stamps = np.asarray(arrays[f"map{k}_stamps"])
        poses = np.asarray(arrays[f"map{k}_poses"])
        if stamps.ndim != 1 or poses.shape != (len(stamps), 4, 4):
            raise SglocError(f"{where}: {len(stamps)} stamps but poses of shape {poses.shape}.")
        for t in stamps:
            check_stamp(where, t)
        check_increasing(where, stamps)
        for T in poses:
            check_rigid(where, T, "a keyframe pose")
        counts = np.asarray(arrays[f"map{k}_counts"])
        sums = np.asarray(arrays[f"map{k}_sums"]).reshape(-1, 3)
        if counts.ndim != 1 or len(counts) != len(sums) or (len(counts) and counts.min() < 1):
            raise SglocError(f"{where}: the map's object counts do not match its objects.")
        check_graph_arrays(f"{where} map", sums / np.maximum(counts, 1)[:, None],
                           arrays[f"map{k}_labels"])
    for key, width in (("last", 2), ("tries", 1), ("refined", 2)):
        _pairs(meta, key, n, width)
    for row in meta.get("links", []):
        _pairs({"links": [row[:2]]}, "links", n, 0, ordered=True)
        d = row[2]
        if (d["robot_a"], d["robot_b"]) != (robots[row[0]], robots[row[1]]):
            raise SglocError(f"link {row[:2]} names robots {d['robot_a']!r}, {d['robot_b']!r}, "
                             f"not {robots[row[0]]!r}, {robots[row[1]]!r}.")
        check_link(f"link {d['robot_a']!r}-{d['robot_b']!r}", d["T_a_b"], d["covariance"],
                   d["confidence"], d["stamp"])
    for k in meta.get("placed", []):
        if not isinstance(k, int) or not 0 <= k < n:
            raise SglocError(f"'placed' entry {k!r:.40} is not a robot index below {n}.")
        check_rigid(f"robot {robots[k]!r}", arrays[f"frame{k}"], "fleet frame")
    if meta.get("keyframes") is not None:
        _check_keyframes(meta["keyframes"], arrays, robots)


def _check_keyframes(kf: dict[str, Any], arrays: dict[str, np.ndarray], robots: list) -> None:
    """The keyframe back-end's part: links between keyframes the robots have, rigid, with a
    valid covariance; the graph's factors between keyframes it has, rigid."""
    sizes = {r: len(arrays[f"map{k}_stamps"]) for k, r in enumerate(robots)}
    for d in kf["links"]:
        where = f"keyframe link {d['robot_a']!r:.40}-{d['robot_b']!r:.40}"
        for r, key in ((d["robot_a"], "keyframe_a"), (d["robot_b"], "keyframe_b")):
            k = d[key]
            if r not in sizes or not isinstance(k, int) or not 0 <= k < sizes[r]:
                raise SglocError(f"{where}: robot {r!r:.40} has no keyframe {k!r:.20}.")
        check_link(where, d["T_a_b"], d["covariance"], d["confidence"], d["stamp"])
    count = np.asarray(arrays["kg_count"], np.int64)
    ends = np.asarray(arrays["kg_ends"], np.int64).reshape(-1, 4)
    if len(count) != len(kf["robots"]) or len(ends) != len(arrays["kg_T"]):
        raise SglocError("the keyframe graph's arrays do not match each other.")
    n_kf = dict(zip(kf["robots"], count.tolist(), strict=True))
    for (ra, ka, rb, kb), T in zip(ends.tolist(), arrays["kg_T"], strict=True):
        if not (0 <= ka < n_kf.get(ra, 0) and 0 <= kb < n_kf.get(rb, 0)):
            raise SglocError(f"a keyframe graph factor joins keyframes it does not have "
                             f"({ra}:{ka}, {rb}:{kb}).")
        check_rigid("a keyframe graph factor", T)
