"""PCD (Point Cloud Library) files holding objects as points: x y z plus a class.

The class comes from a `label` field when present, else from a packed `rgb` field looked up in
a colour table (Guo et al.'s Airsim table by default). DATA ascii, binary and
binary_compressed (LZF). The reader is strict: every header line is checked against the others
and against the data (counts, sizes, trailing bytes), so a damaged file is an error, never a
silently shorter map. """

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sgloc.errors import GraphFileError
from sgloc.io.files import read_regular_file
from sgloc.io.lzf import LZFError, lzf_compress, lzf_decompress
from sgloc.maps.classes import AIRSIM_COLORS, colors_to_labels, pack_rgb, unpack_rgb

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
_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS")
_VERSIONS = {"0.7", ".7", "0.6", ".6", "0.5", ".5"}
_MODES = ("ascii", "binary", "binary_compressed")
_MAX_HEADER_BYTES = 1 << 16
_WHAT = ".pcd graph file"
#: Bytes an ASCII PCD data section may hold: numbers (with nan / inf) and blanks. Python's float()
#: would also read "1_0", and str.split() splits numbers at control bytes.
_ASCII_DATA = re.compile(r"[^0-9eE.+\-nNaAiIfFtTyY \t\r\n]")
#: An integer field's value, as PCL writes it ("5.", "1e-400" or "1_0" are not integers).
_INTEGER = re.compile(r"[+-]?[0-9]+")


@dataclass(frozen=True)
class PcdHeader:
    """The checked header: one entry per field; n points; data mode; where the data starts."""

    fields: list[str]
    types: list[str]
    sizes: list[int]
    counts: list[int]
    n: int
    mode: str
    offset: int

    @property
    def dtype(self) -> np.dtype:
        """The binary record of one point."""
        spec = zip(self.fields, self.types, self.sizes, self.counts, strict=True)
        return np.dtype([(f, _NP_TYPES[(t, s)], (c,)) for f, t, s, c in spec])


def _bad(path: Path, message: str) -> GraphFileError:
    return GraphFileError(f"{path}: malformed PCD header: {message}")


def _header_lines(raw: bytes, path: Path) -> tuple[dict[str, list[str]], int]:
    """{KEY: values} of the header lines up to DATA, and the offset of the first data byte."""
    header: dict[str, list[str]] = {}
    offset = 0
    while True:
        end = raw.find(b"\n", offset, _MAX_HEADER_BYTES)
        if end < 0:
            raise GraphFileError(f"{path}: PCD header has no DATA line; is this a .pcd file?")
        try:
            line = raw[offset:end].decode("ascii").strip()
        except UnicodeDecodeError:
            raise _bad(path, f"non-ASCII bytes in the header line at byte {offset}") from None
        offset = end + 1
        if not line or line.startswith("#"):
            continue
        key, *vals = line.split()
        key = key.upper()
        if key in header:
            raise _bad(path, f"the {key} line appears twice; keep one")
        if key != "DATA" and key not in _KEYS:
            raise _bad(path, f"unknown header line {key!r}")
        header[key] = vals
        if key == "DATA":
            return header, offset


def _ints(path: Path, header: dict[str, list[str]], key: str, minimum: int) -> list[int]:
    try:
        vals = [int(v) for v in header[key]]
    except ValueError:
        raise _bad(path, f"{key} must hold integers, got {' '.join(header[key])!r}") from None
    if any(v < minimum for v in vals):
        raise _bad(path, f"{key} values must be >= {minimum}, got {' '.join(header[key])}")
    return vals


def _one_int(path: Path, header: dict[str, list[str]], key: str) -> int:
    vals = _ints(path, header, key, 0)
    if len(vals) != 1:
        raise _bad(path, f"{key} must hold one number, got {len(vals)}")
    return vals[0]


def parse_header(raw: bytes, path: Path) -> PcdHeader:
    """Check the header of a PCD file's bytes: every line once, lengths, types, counts."""
    header, offset = _header_lines(raw, path)
    for key in ("FIELDS", "SIZE", "TYPE"):
        if key not in header:
            raise _bad(path, f"no {key} line")
    if "WIDTH" not in header and "POINTS" not in header:
        raise _bad(path, "no WIDTH or POINTS line; give the number of points")
    if "VERSION" in header and " ".join(header["VERSION"]) not in _VERSIONS:
        raise _bad(path, f"VERSION {' '.join(header['VERSION'])!r} is not a PCD version (0.7)")
    fields = [f.lower() for f in header["FIELDS"]]
    types = [t.upper() for t in header["TYPE"]]
    sizes = _ints(path, header, "SIZE", 1)
    counts = _ints(path, header, "COUNT", 1) if "COUNT" in header else [1] * len(fields)
    lengths = {"FIELDS": len(fields), "SIZE": len(sizes), "TYPE": len(types)}
    lengths["COUNT"] = len(counts)
    if len(set(lengths.values())) != 1 or not fields:
        listed = ", ".join(f"{k} {v}" for k, v in lengths.items())
        raise _bad(path, f"FIELDS, SIZE, TYPE and COUNT must list one entry per field ({listed})")
    if len(set(fields)) != len(fields):
        raise _bad(path, f"a field is listed twice in FIELDS {' '.join(fields)}")
    for f, t, s in zip(fields, types, sizes, strict=True):
        if (t, s) not in _NP_TYPES:
            raise _bad(path, f"field {f!r} has TYPE {t} SIZE {s}; use F 4/8, U or I 1/2/4/8")
    n = _one_int(path, header, "POINTS") if "POINTS" in header else None
    if "WIDTH" in header:
        width = _one_int(path, header, "WIDTH")
        height = _one_int(path, header, "HEIGHT") if "HEIGHT" in header else 1
        if n is not None and n != width * height:
            raise _bad(path, f"POINTS {n} is not WIDTH x HEIGHT = {width} x {height}")
        n = width * height
    elif "HEIGHT" in header:
        raise _bad(path, "HEIGHT without WIDTH")
    if "VIEWPOINT" in header and len(header["VIEWPOINT"]) != 7:
        raise _bad(path, "VIEWPOINT must hold 7 numbers (tx ty tz qw qx qy qz)")
    mode = " ".join(header["DATA"]).lower()
    if mode not in _MODES:
        raise GraphFileError(
            f"{path}: PCD DATA {mode!r} is not supported; save as ascii, binary or "
            "binary_compressed."
        )
    return PcdHeader(fields, types, sizes, counts, n, mode, offset)


def _ascii_columns(raw: bytes, h: PcdHeader, path: Path) -> dict[str, np.ndarray]:
    try:
        text = raw[h.offset :].decode("ascii")
    except UnicodeDecodeError:
        raise GraphFileError(
            f"{path}: non-ASCII bytes in ASCII PCD data; the file is damaged or not DATA ascii."
        ) from None
    stray = _ASCII_DATA.search(text)
    if stray is not None:
        raise GraphFileError(
            f"{path}: non-numeric character {stray.group()!r} in the ASCII PCD data (byte "
            f"{h.offset + stray.start()}); every value must be a plain number."
        )
    rows = [r for r in (line.split() for line in text.splitlines()) if r]
    if len(rows) != h.n:
        raise GraphFileError(
            f"{path}: the header says POINTS {h.n}, but the data holds {len(rows)} rows; the file "
            "is truncated or has extra data (fix POINTS/WIDTH or the data)."
        )
    width = sum(h.counts)
    wrong = next((k for k, r in enumerate(rows) if len(r) != width), None)
    if wrong is not None:
        raise GraphFileError(
            f"{path}: data row {wrong} holds {len(rows[wrong])} values; FIELDS/COUNT give {width}."
        )
    try:
        table = np.array(rows, dtype=np.float64).reshape(h.n, width)
    except ValueError:
        raise GraphFileError(
            f"{path}: non-numeric value in the PCD data; every value must be a number."
        ) from None
    cols, start = {}, 0
    for f, t, s, c in zip(h.fields, h.types, h.sizes, h.counts, strict=True):
        col = table[:, start : start + c]
        start += c
        if t in "UI":
            _check_integer_text(rows, start - c, c, f, path)
            info = np.iinfo(np.dtype(_NP_TYPES[(t, s)]))
            if np.any(col != np.round(col)) or np.any((col < info.min) | (col > info.max)):
                raise GraphFileError(
                    f"{path}: field {f!r} is TYPE {t} SIZE {s} but holds values that are not "
                    f"integers in [{info.min}, {info.max}]."
                )
            col = col.astype(np.int64) if t == "I" or s < 8 else col.astype(np.uint64)
        elif f in ("rgb", "rgba") and s == 4:  # a packed colour stored as a float32's bits
            col = col.astype(np.float32).view(np.uint32)
        cols[f] = col
    return cols


def _check_integer_text(rows: list[list[str]], first: int, count: int, field: str, path: Path):
    """Every value of an integer field written as an integer (digits, an optional sign)."""
    for k, row in enumerate(rows):
        for value in row[first : first + count]:
            if not _INTEGER.fullmatch(value):
                raise GraphFileError(
                    f"{path}: data row {k}: field {field!r} is an integer field but holds "
                    f"{value!r}; values that are not integers in plain digits are refused."
                )


def _binary_columns(raw: bytes, h: PcdHeader, path: Path) -> dict[str, np.ndarray]:
    dtype = h.dtype
    data = raw[h.offset :]
    need = h.n * dtype.itemsize
    if h.mode == "binary":
        if len(data) != need:
            what = "truncated" if len(data) < need else "followed by extra bytes"
            raise GraphFileError(
                f"{path}: binary PCD data is {what}: {len(data)} bytes for POINTS {h.n} of "
                f"{dtype.itemsize} bytes each ({need}); fix POINTS or re-save the file."
            )
        rec = np.frombuffer(data, dtype=dtype, count=h.n)
        return {f: rec[f].reshape(h.n, -1) for f in h.fields}
    if len(data) < 8:
        raise GraphFileError(
            f"{path}: binary_compressed PCD data is truncated (no sizes); re-save the file."
        )
    packed, unpacked = np.frombuffer(data[:8], dtype="<u4").tolist()
    if unpacked != need:
        raise GraphFileError(
            f"{path}: binary_compressed data announces {unpacked} bytes, but POINTS {h.n} of "
            f"{dtype.itemsize} bytes each need {need}; fix POINTS or re-save the file."
        )
    if len(data) - 8 != packed:
        what = "truncated" if len(data) - 8 < packed else "followed by extra bytes"
        raise GraphFileError(f"{path}: binary_compressed PCD data is {what}; re-save the file.")
    try:
        flat = lzf_decompress(data[8:], unpacked)
    except LZFError as e:
        raise GraphFileError(f"{path}: corrupt binary_compressed PCD data ({e}).") from None
    cols, start = {}, 0
    for f in h.fields:  # field-major layout: all points of one field, then the next field
        sub = dtype[f]
        cols[f] = np.frombuffer(flat, dtype=sub.base, count=h.n * sub.shape[0], offset=start)
        cols[f] = cols[f].reshape(h.n, -1)
        start += h.n * sub.itemsize
    return cols


def _column(cols: dict[str, np.ndarray], name: str, path: Path) -> np.ndarray:
    col = cols[name]
    if col.shape[1] != 1:
        raise GraphFileError(f"{path}: field {name!r} must have COUNT 1, has {col.shape[1]}.")
    return col[:, 0]


# Damaged data may hold signalling NaNs or out-of-range floats: casting them must not print
# warnings (the values are checked here and by sgloc.validation).
@np.errstate(invalid="ignore", over="ignore")
def read_pcd(path: str | Path, colors: np.ndarray = AIRSIM_COLORS) -> tuple[np.ndarray, np.ndarray]:
    """Read object positions (n,3) and class ids (n,) from a PCD file; GraphFileError if bad."""
    path = Path(path)
    raw = read_regular_file(path, _WHAT)
    h = parse_header(raw, path)
    if not {"x", "y", "z"} <= set(h.fields):
        raise GraphFileError(f"{path}: PCD needs fields x y z, has {' '.join(h.fields)}.")
    if "label" not in h.fields and "rgb" not in h.fields and "rgba" not in h.fields:
        raise GraphFileError(
            f"{path}: PCD has no class field; add a `label` field or a packed `rgb` colour."
        )
    cols = _ascii_columns(raw, h, path) if h.mode == "ascii" else _binary_columns(raw, h, path)
    positions = np.stack([_column(cols, a, path) for a in "xyz"], axis=1).astype(np.float64)
    if "label" in cols:
        labels = _column(cols, "label", path).astype(np.float64)
        if not np.all(np.isfinite(labels)) or np.any(labels != np.round(labels)):
            raise GraphFileError(
                f"{path}: the label field must hold integer class ids >= 0; fix the labels."
            )
        return positions, labels.astype(np.int64)
    name = "rgb" if "rgb" in cols else "rgba"
    col = _column(cols, name, path)
    if col.dtype.kind == "f":  # binary float32 rgb: the bits are the packed colour
        if col.dtype.itemsize != 4:
            raise GraphFileError(f"{path}: field {name!r} must be 4 bytes (packed RGB).")
        col = col.view(np.uint32)
    packed = col.astype(np.int64) & 0xFFFFFF
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
    path: str | Path,
    positions: np.ndarray,
    labels: np.ndarray,
    colors: np.ndarray = AIRSIM_COLORS,
    data: str = "ascii",
) -> None:
    """Write a PCD with fields x y z rgb label (rgb from the colour table).

    data: "ascii" (default), "binary" or "binary_compressed" (LZF, field-major as PCL writes it).
    """
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    labels = np.asarray(labels).astype(np.int64).reshape(-1)
    n = len(positions)
    rgb = pack_rgb(colors[labels % len(colors)]).astype(np.uint32)
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z rgb label\n"
        "SIZE 4 4 4 4 4\nTYPE F F F U U\nCOUNT 1 1 1 1 1\n"
        f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n"
    )
    if data == "ascii":
        rows = "".join(
            f"{x:.6f} {y:.6f} {z:.6f} {c} {lab}\n"
            for (x, y, z), c, lab in zip(positions, rgb, labels, strict=True)
        )
        Path(path).write_text(header + rows)
        return
    columns = [positions[:, k].astype("<f4") for k in range(3)]
    columns += [rgb.astype("<u4"), labels.astype("<u4")]
    if data == "binary":
        body = np.rec.fromarrays(columns, names="x,y,z,rgb,label").tobytes()
    elif data == "binary_compressed":
        flat = b"".join(c.tobytes() for c in columns)
        packed = lzf_compress(flat)
        body = np.array([len(packed), len(flat)], dtype="<u4").tobytes() + packed
    else:
        raise GraphFileError(f"PCD DATA {data!r}: use ascii, binary or binary_compressed.")
    Path(path).write_bytes(header.encode("ascii") + body)
