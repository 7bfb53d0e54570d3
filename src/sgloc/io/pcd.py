"""PCD (Point Cloud Library) files holding objects as points: x y z plus a class.

The class comes from a `label` field when present, else from a packed `rgb` field looked up in
a colour table (Guo et al.'s Airsim table by default). ASCII and binary (uncompressed) data.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sgloc.classes import AIRSIM_COLORS, colors_to_labels, pack_rgb, unpack_rgb
from sgloc.errors import GraphFileError

_NP_TYPES = {
    ("F", 4): "<f4",
    ("F", 8): "<f8",
    ("U", 1): "<u1",
    ("U", 2): "<u2",
    ("U", 4): "<u4",
    ("U", 8): "<u8",
    ("I", 1): "<i1",
    ("I", 2): "<i2",
    ("I", 4): "<i4",
    ("I", 8): "<i8",
}


def _parse_header(raw: bytes, path: Path) -> tuple[dict[str, list[str]], int]:
    header: dict[str, list[str]] = {}
    offset = 0
    while True:
        end = raw.find(b"\n", offset)
        if end < 0:
            raise GraphFileError(f"{path}: PCD header has no DATA line; is this a .pcd file?")
        line = raw[offset:end].decode("ascii", errors="replace").strip()
        offset = end + 1
        if not line or line.startswith("#"):
            continue
        key, *vals = line.split()
        header[key.upper()] = vals
        if key.upper() == "DATA":
            return header, offset


def read_pcd(path: str | Path, colors: np.ndarray = AIRSIM_COLORS) -> tuple[np.ndarray, np.ndarray]:
    """Read object positions (n,3) and class ids (n,) from a PCD file."""
    path = Path(path)
    raw = path.read_bytes()
    header, offset = _parse_header(raw, path)
    try:
        fields = [f.lower() for f in header["FIELDS"]]
        sizes = [int(s) for s in header["SIZE"]]
        types = [t.upper() for t in header["TYPE"]]
        counts = [int(c) for c in header.get("COUNT", ["1"] * len(fields))]
        n = (
            int(header["POINTS"][0])
            if "POINTS" in header
            else int(header["WIDTH"][0]) * int(header.get("HEIGHT", ["1"])[0])
        )
        mode = header["DATA"][0].lower()
    except (KeyError, ValueError, IndexError) as e:
        raise GraphFileError(
            f"{path}: malformed PCD header ({e}); expected FIELDS/SIZE/TYPE/POINTS."
        ) from e
    if not {"x", "y", "z"} <= set(fields):
        raise GraphFileError(f"{path}: PCD needs fields x y z, has {' '.join(fields)}.")
    if "label" not in fields and "rgb" not in fields and "rgba" not in fields:
        raise GraphFileError(
            f"{path}: PCD has no class field; add a `label` field or a packed `rgb` colour."
        )
    if any(c != 1 for c in counts):
        raise GraphFileError(f"{path}: PCD fields with COUNT > 1 are not supported.")
    if mode == "ascii":
        text = raw[offset:].decode("ascii", errors="replace").split()
        if len(text) < n * len(fields):
            raise GraphFileError(
                f"{path}: header says {n} points of {len(fields)} fields, but the data holds "
                f"{len(text)} values; the file is truncated or malformed."
            )
        try:
            table = np.array(text[: n * len(fields)], dtype=np.float64).reshape(n, len(fields))
        except ValueError as e:
            raise GraphFileError(f"{path}: non-numeric value in PCD data ({e}).") from e
        cols = {f: table[:, k] for k, f in enumerate(fields)}
        if "rgb" in cols and types[fields.index("rgb")] == "F":
            cols["rgb"] = cols["rgb"].astype(np.float32).view(np.uint32).astype(np.float64)
    elif mode == "binary":
        try:
            spec = zip(fields, types, sizes, strict=True)
            dtype = np.dtype([(f, _NP_TYPES[(t, s)]) for f, t, s in spec])
        except KeyError as e:
            raise GraphFileError(f"{path}: unsupported PCD field type {e}.") from e
        if len(raw) - offset < n * dtype.itemsize:
            raise GraphFileError(f"{path}: binary PCD data is truncated.")
        rec = np.frombuffer(raw, dtype=dtype, count=n, offset=offset)
        cols = {f: rec[f] for f in fields}
        if "rgb" in cols and cols["rgb"].dtype == np.float32:
            cols["rgb"] = cols["rgb"].view(np.uint32)
    else:
        raise GraphFileError(
            f"{path}: PCD DATA {mode!r} is not supported; save as ascii or binary."
        )
    positions = np.stack([cols["x"], cols["y"], cols["z"]], axis=1).astype(np.float64)
    if "label" in cols:
        labels = np.asarray(cols["label"]).astype(np.int64)
    else:
        packed = np.asarray(cols.get("rgb", cols.get("rgba"))).astype(np.int64) & 0xFFFFFF
        labels = colors_to_labels(unpack_rgb(packed), colors)
        unknown = np.flatnonzero(labels < 0)
        if unknown.size:
            rgb = tuple(int(v) for v in unpack_rgb(packed[unknown[:1]])[0])
            raise GraphFileError(
                f"{path}: {unknown.size} point(s) have a colour that is not in the class table "
                f"(first: RGB {rgb} at point {unknown[0]}); pass the dataset's colour table or "
                "write a `label` field."
            )
    return positions, labels


def write_pcd(
    path: str | Path, positions: np.ndarray, labels: np.ndarray, colors: np.ndarray = AIRSIM_COLORS
) -> None:
    """Write an ASCII PCD with fields x y z rgb label (rgb from the colour table)."""
    n = len(positions)
    rgb = pack_rgb(colors[np.asarray(labels) % len(colors)])
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z rgb label\n"
        "SIZE 4 4 4 4 4\nTYPE F F F U U\nCOUNT 1 1 1 1 1\n"
        f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA ascii\n"
    )
    rows = "".join(
        f"{x:.6f} {y:.6f} {z:.6f} {c} {lab}\n"
        for (x, y, z), c, lab in zip(np.asarray(positions), rgb, np.asarray(labels), strict=True)
    )
    Path(path).write_text(header + rows)
