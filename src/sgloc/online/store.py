"""Save and resume an OnlineSession: one .npz holding the robots' map arrays and a JSON
document with everything else."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from sgloc.errors import SglocError

FORMAT = "sgloc-online-session-1"


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
    """The session saved at `path` (`cls.from_state`)."""
    p = Path(path)
    try:
        with np.load(p, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files if k != "meta"}
            meta = json.loads(str(z["meta"]))
    except (OSError, ValueError, KeyError) as e:
        raise SglocError(
            f"{p}: not a saved online session ({e}); write one with OnlineSession.save."
        ) from None
    if meta.get("format") != FORMAT:
        raise SglocError(f"{p}: unknown session format {meta.get('format')!r} (need {FORMAT}).")
    try:
        return cls.from_state(meta, arrays)
    except (KeyError, TypeError, ValueError) as e:
        raise SglocError(f"{p}: a damaged online session ({e!r}).") from None
