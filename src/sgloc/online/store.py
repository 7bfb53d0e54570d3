"""Save and resume an OnlineSession: one .npz holding the robots' map arrays and a JSON
document with everything else."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from sgloc.config import LocalizerConfig
from sgloc.errors import SglocError
from sgloc.online.config import OnlineConfig
from sgloc.online.records import Attempt, Event, Link
from sgloc.online.robot_map import RobotMap

FORMAT = "sgloc-online-session-1"


def save_session(session, path: str | Path) -> Path:
    """Write `session` to `path` (.npz appended when missing)."""
    p = Path(path)
    if p.suffix != ".npz":
        p = p.with_name(p.name + ".npz")
    p.parent.mkdir(parents=True, exist_ok=True)
    names = session.robots
    meta = {
        "format": FORMAT,
        "config": session.config.to_dict(),
        "online": session.online.to_dict(),
        "root": session._root,
        "robots": names,
        "last": [[i, j, *v] for (i, j), v in sorted(session._last.items())],
        "tries": [[i, j, v] for (i, j), v in sorted(session._tries.items())],
        "links": [[i, j, lk.to_dict()] for (i, j), lk in sorted(session._links.items())],
        "placed": sorted(session._T),
        "attempts": [a.to_dict() for a in session.attempts],
        "events": [e.to_dict() for e in session.events],
    }
    arrays = {"meta": np.array(json.dumps(meta))}
    for k, r in enumerate(names):
        for key, arr in session._maps[r].state().items():
            arrays[f"map{k}_{key}"] = arr
    np.savez_compressed(p, **arrays)
    return p


def load_session(cls, path: str | Path):
    """The session saved at `path` (its fleet frame re-solved from the saved links)."""
    p = Path(path)
    try:
        with np.load(p, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
        meta = json.loads(str(data["meta"]))
    except (OSError, ValueError, KeyError) as e:
        raise SglocError(
            f"{p}: not a saved online session ({e}); write one with OnlineSession.save."
        ) from None
    if meta.get("format") != FORMAT:
        raise SglocError(f"{p}: unknown session format {meta.get('format')!r} (need {FORMAT}).")
    s = cls(LocalizerConfig.from_dict(meta["config"]), OnlineConfig.from_dict(meta["online"]),
            meta["root"])
    o = s.online
    for k, r in enumerate(meta["robots"]):
        m = RobotMap(r, o.association_radius, o.min_observations, o.edge_radius)
        prefix = f"map{k}_"
        m.set_state({key[len(prefix):]: v for key, v in data.items() if key.startswith(prefix)})
        s._maps[r] = m
    s._last = {(i, j): (a, b) for i, j, a, b in meta["last"]}
    s._tries = {(i, j): v for i, j, v in meta["tries"]}
    s._links = {(i, j): Link.from_dict(d) for i, j, d in meta["links"]}
    s.attempts = [Attempt.from_dict(d) for d in meta["attempts"]]
    s.events = [Event.from_dict(d) for d in meta["events"]]
    if s.robots:
        s._refresh(0.0, emit=False)
    return s
