"""Strict graph/pose readers: every malformed file is a GraphFileError/InvalidGraphError (an
SglocError) naming the file, never a traceback, a hang or a silently shorter map."""

import json
import os
import zipfile

import numpy as np
import pytest

from sgloc.errors import DatasetError, GraphFileError, InvalidGraphError, SglocError
from sgloc.io import read_graph
from sgloc.io.lzf import LZFError, lzf_compress, lzf_decompress
from sgloc.io.pcd import read_pcd, write_pcd
from sgloc.io.poses import read_kitti_poses
from sgloc.validation import MAX_CLASSES, MAX_COORDINATE

HEADER = "VERSION 0.7\nFIELDS x y z label\nSIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\n"
ROWS = "0 0 0 1\n10 0 0 2\n0 10 0 3\n"


def pcd(tmp_path, text: str, name: str = "g.pcd"):
    p = tmp_path / name
    p.write_bytes(text.encode() if isinstance(text, str) else text)
    return p


def good_pcd(points: int = 3, width: int | None = None, height: int = 1, rows: str = ROWS) -> str:
    width = points if width is None else width
    return HEADER + f"WIDTH {width}\nHEIGHT {height}\nPOINTS {points}\nDATA ascii\n" + rows


def test_well_formed_pcd_reads(tmp_path):
    pos, lab = read_graph(pcd(tmp_path, good_pcd()))
    assert pos.shape == (3, 3) and lab.tolist() == [1, 2, 3]


@pytest.mark.parametrize(
    "text, message",
    [
        (good_pcd(points=-1), "POINTS values must be >= 0"),
        (good_pcd(points=2, width=2), "POINTS 2, but the data holds 3 rows"),
        (good_pcd(points=4, width=4), "POINTS 4, but the data holds 3 rows"),
        (good_pcd(points=3, width=2), r"not WIDTH x HEIGHT"),
        (good_pcd(points=3, width=3, height=2), r"not WIDTH x HEIGHT"),
        (good_pcd().replace("POINTS 3\n", "POINTS 3\nPOINTS 3\n"), "appears twice"),
        (good_pcd().replace("TYPE F F F U", "TYPE F F F"), "one entry per field"),
        (good_pcd().replace("SIZE 4 4 4 4", "SIZE 4 4 4"), "one entry per field"),
        (good_pcd().replace("COUNT 1 1 1 1", "COUNT 1 1"), "one entry per field"),
        (good_pcd().replace("VERSION 0.7", "VERSION 9"), "VERSION"),
        (good_pcd().replace("TYPE F F F U", "TYPE F F F Q"), "TYPE Q"),
        (good_pcd().replace("DATA ascii", "DATA binary_lz4"), "not supported"),
        (good_pcd().replace("WIDTH 3", "WIDTH x"), "integers"),
        (good_pcd().replace("FIELDS x y z label", "FIELDS x y y label"), "listed twice"),
        (good_pcd().replace("HEIGHT 1\n", "HEIGHT 1\nCOLOR 2\n"), "unknown header line"),
        (good_pcd(rows="0 0 0 1\n10 0 0\n0 10 0 3\n"), "row 1 holds 3 values"),
        (good_pcd(rows="0 0 0 1\n10 0 0 2.5\n0 10 0 3\n"), "not integers"),
        (good_pcd(rows="0 0 0 1\n10 0 0 -2\n0 10 0 3\n"), "not integers"),
        (good_pcd(rows="0 0 0 1\n10 0 0 x\n0 10 0 3\n"), "non-numeric"),
        (good_pcd(rows="0 0 0 1\n10 nan 0 2\n0 10 0 3\n"), "NaN"),
        (good_pcd(rows="0 0 0 1\n1e200 0 0 2\n0 10 0 3\n"), "beyond"),
        ("FIELDS x y z label\nSIZE 4 4 4 4\n", "no DATA line"),
    ],
)
def test_malformed_pcd_is_an_error(tmp_path, text, message):
    with pytest.raises(SglocError, match=message) as err:
        read_graph(pcd(tmp_path, text))
    assert "g.pcd" in str(err.value)


def test_binary_pcd_counts_are_enforced(tmp_path):
    pos = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0]], float)
    p = tmp_path / "b.pcd"
    write_pcd(p, pos, [1, 2, 3], data="binary")
    assert read_pcd(p)[1].tolist() == [1, 2, 3]
    raw = p.read_bytes()
    p.write_bytes(raw + raw[-20:])  # one extra record
    with pytest.raises(GraphFileError, match="extra bytes"):
        read_pcd(p)
    p.write_bytes(raw[:-3])
    with pytest.raises(GraphFileError, match="truncated"):
        read_pcd(p)


@pytest.mark.parametrize("data", ["ascii", "binary", "binary_compressed"])
def test_pcd_round_trip_every_data_mode(tmp_path, airsim_graphs, data):
    g = airsim_graphs[0]
    p = tmp_path / f"{data}.pcd"
    write_pcd(p, g.positions, g.labels, data=data)
    pos, lab = read_pcd(p)
    np.testing.assert_allclose(pos, g.positions, atol=1e-5)
    assert np.array_equal(lab, g.labels)


def test_binary_compressed_damage_is_an_error(tmp_path, airsim_graphs):
    g = airsim_graphs[0]
    p = tmp_path / "c.pcd"
    write_pcd(p, g.positions, g.labels, data="binary_compressed")
    raw = p.read_bytes()
    for bad, message in [
        (raw[:-5], "truncated"),
        (raw + b"\0", "extra bytes"),
        (raw.replace(b"POINTS 318", b"POINTS 319").replace(b"WIDTH 318", b"WIDTH 319"), "need"),
    ]:
        p.write_bytes(bad)
        with pytest.raises(GraphFileError, match=message):
            read_pcd(p)


def test_lzf_round_trip_and_corruption():
    data = np.repeat(np.arange(50, dtype=np.uint32), 40).tobytes() + os.urandom(300)
    packed = lzf_compress(data)
    assert len(packed) < len(data) and lzf_decompress(packed, len(data)) == data
    with pytest.raises(LZFError):
        lzf_decompress(packed, len(data) - 1)
    with pytest.raises(LZFError):
        lzf_decompress(b"\xe0\xff\xff", 100)  # back-reference before the start
    with pytest.raises(LZFError):
        lzf_decompress(b"\x1f", 32)  # literal run past the end


def test_fifo_and_folder_are_refused_without_blocking(tmp_path):
    fifo = tmp_path / "pipe.pcd"
    os.mkfifo(fifo)
    with pytest.raises(GraphFileError, match="not a regular file"):
        read_graph(fifo)
    folder = tmp_path / "dir.json"
    folder.mkdir()
    with pytest.raises(GraphFileError, match="is a folder"):
        read_graph(folder)
    with pytest.raises(DatasetError, match="not a regular file"):
        read_kitti_poses(fifo)


def write_json(tmp_path, text: str):
    p = tmp_path / "g.json"
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    "labels, message",
    [
        ("[true, 1, 2]", "integer class ids"),
        ('["7", 1, 2]', "integer class ids"),
        ("[1.5, 1, 2]", "integer class ids"),
        ("[1, 2]", "labels must have shape"),
    ],
)
def test_json_labels_must_be_integers(tmp_path, labels, message):
    p = write_json(tmp_path, '{"positions": [[0,0,0],[1,0,0],[0,1,0]], "labels": ' + labels + "}")
    with pytest.raises(SglocError, match=message):
        read_graph(p)


@pytest.mark.parametrize(
    "position, message",
    [
        ("1e400", "float range"),
        ("1" + "0" * 400, "digits"),
        ("NaN", "finite"),
        ("Infinity", "finite"),
        ('"3"', "rows of numbers"),
        ("true", "rows of numbers"),
        ("1e200", "beyond"),
    ],
)
def test_json_numbers_must_be_finite_reals(tmp_path, position, message):
    text = '{"positions": [[0,0,0],[1,0,' + position + '],[0,1,0]], "labels": [1,2,3]}'
    with pytest.raises(SglocError, match=message):
        read_graph(write_json(tmp_path, text))


def test_json_duplicate_keys_are_refused(tmp_path):
    text = '{"positions": [[0,0,0]], "labels": [1], "labels": [2]}'
    with pytest.raises(GraphFileError, match="appears twice"):
        read_graph(write_json(tmp_path, text))


def test_nan_detection_centroids_are_refused():
    from sgloc.datasets.kitti_objects import parse_centroids

    with pytest.raises(DatasetError, match="NaN or infinite"):
        parse_centroids(b"1 2 3\nnan 0 0\n", "centroids/000001.txt")


def test_json_depth_is_bounded(tmp_path):
    with pytest.raises(GraphFileError, match="nested deeper"):
        read_graph(write_json(tmp_path, "[" * 100_000 + "]" * 100_000))


def test_json_round_trip(tmp_path):
    p = write_json(tmp_path, json.dumps({"positions": [[0, 0, 0], [1.5, 2, 3]], "labels": [4, 0]}))
    pos, lab = read_graph(p)
    assert pos.tolist() == [[0, 0, 0], [1.5, 2, 3]] and lab.tolist() == [4, 0]


def npz(tmp_path, **arrays):
    p = tmp_path / "g.npz"
    np.savez(p, **arrays)
    return p


POS = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0]], float)


@pytest.mark.parametrize(
    "arrays, message",
    [
        ({"positions": POS, "labels": np.array([True, False, True])}, "integer"),
        ({"positions": POS, "labels": np.array([1.0, 2.0, 3.0])}, "integer"),
        ({"positions": POS.astype(complex), "labels": np.arange(3)}, "real"),
        ({"positions": POS.astype(str), "labels": np.arange(3)}, "real"),
        ({"positions": POS.astype("datetime64[s]"), "labels": np.arange(3)}, "real"),
        ({"positions": np.zeros((3, 4)), "labels": np.arange(4)}, r"\(n, 3\)"),
        ({"positions": POS}, "missing labels"),
        ({"positions": POS, "labels": np.array([1, 2, 3], dtype=object)}, "g.npz"),
    ],
)
def test_npz_dtype_and_shape_checks(tmp_path, arrays, message):
    with pytest.raises(SglocError, match=message):
        read_graph(npz(tmp_path, **arrays))


def test_npz_three_by_n_is_not_reshaped(tmp_path):
    pts = np.arange(12, dtype=float).reshape(3, 4)  # 4 points stored as (3, n)
    with pytest.raises(GraphFileError, match=r"\(n, 3\)"):
        read_graph(npz(tmp_path, positions=pts, labels=np.arange(4)))


def test_corrupt_npz_is_an_error(tmp_path):
    p = npz(tmp_path, positions=POS, labels=np.arange(3))
    raw = p.read_bytes()
    for bad in (raw[: len(raw) // 2], raw[:40] + b"\xff" * 40 + raw[80:], b"PK\x03\x04junk"):
        p.write_bytes(bad)
        with pytest.raises(GraphFileError, match="g.npz"):
            read_graph(p)
    np.save(tmp_path / "a.npy", POS)
    os.replace(tmp_path / "a.npy", p)
    with pytest.raises(GraphFileError, match="single .npy array"):
        read_graph(p)


def test_compressed_npz_with_flipped_bytes(tmp_path):
    p = tmp_path / "g.npz"
    np.savez_compressed(
        p, positions=np.random.default_rng(0).normal(size=(200, 3)), labels=np.arange(200) % 5
    )
    raw = bytearray(p.read_bytes())
    with zipfile.ZipFile(p) as zf:
        start = zf.infolist()[0].header_offset + 60
    raw[start : start + 20] = b"\x00" * 20
    p.write_bytes(bytes(raw))
    with pytest.raises(GraphFileError, match="g.npz"):
        read_graph(p)


def test_colours_read_as_labels_hit_the_class_limit(tmp_path):
    rows = "".join(f"{i} {i % 7} 0 {i * 9973 % 16777216}\n" for i in range(MAX_CLASSES + 5))
    n = MAX_CLASSES + 5
    text = HEADER + f"WIDTH {n}\nHEIGHT 1\nPOINTS {n}\nDATA ascii\n" + rows
    with pytest.raises(InvalidGraphError, match="distinct classes"):
        read_graph(pcd(tmp_path, text))


def test_coordinate_limit(tmp_path):
    p = write_json(
        tmp_path,
        json.dumps({"positions": [[0, 0, 0], [MAX_COORDINATE * 1.01, 0, 0]], "labels": [0, 0]}),
    )
    with pytest.raises(InvalidGraphError, match="beyond"):
        read_graph(p)


def test_signalling_nan_is_an_error_without_warnings(tmp_path, recwarn):
    pos = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0]], float)
    p = tmp_path / "snan.pcd"
    write_pcd(p, pos, [1, 2, 3], data="binary")
    raw = bytearray(p.read_bytes())
    start = len(raw) - 3 * 20  # first record; x is its first 4 bytes
    raw[start : start + 4] = np.array([0x7F800001], "<u4").tobytes()
    p.write_bytes(bytes(raw))
    with pytest.raises(InvalidGraphError, match="NaN or infinite"):
        read_graph(p)
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]


def test_encrypted_flag_in_npz_is_an_error(tmp_path):
    p = npz(tmp_path, positions=POS, labels=np.arange(3))
    raw = bytearray(p.read_bytes())
    central = bytes(raw).index(b"PK\x01\x02")
    raw[central + 8] |= 1  # the first member's general-purpose flag: "encrypted"
    p.write_bytes(bytes(raw))
    with pytest.raises(GraphFileError, match="damaged .npz"):
        read_graph(p)
