"""`sgloc demo --out`: every picture format sgloc draws works with no traceback and no warning, a
format it does not draw is one `error:` line naming those it does, a folder gets aligned_maps.png
in it, and a second run replaces the picture sgloc drew but never a user's file."""

from __future__ import annotations

import logging
import warnings
from pathlib import Path

import matplotlib
import pytest

from sgloc.cli import main
from sgloc.io.files import is_sgloc_picture
from sgloc.io.pictures import PICTURE_FORMATS, picture_formats, save_picture

matplotlib.use("Agg")


def _figure():
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(2, 2))
    ax.scatter([0, 1], [1, 0], alpha=0.5)  # translucent, as the maps' dots are
    return fig


@pytest.mark.parametrize("fmt", PICTURE_FORMATS)
def test_each_format_is_drawn_marked_and_told_from_a_users_picture(tmp_path, fmt, caplog):
    if fmt not in picture_formats():
        pytest.skip(f"this Pillow does not write {fmt}")
    fig = _figure()
    with warnings.catch_warnings(record=True) as seen, caplog.at_level(logging.WARNING):
        warnings.simplefilter("always")
        save_picture(fig, tmp_path / f"ours.{fmt}")
    assert [str(w.message) for w in seen] == [] and caplog.records == []
    assert is_sgloc_picture(tmp_path / f"ours.{fmt}")
    fig.savefig(tmp_path / f"users.{fmt}", format=fmt)  # the same picture, not drawn by sgloc
    assert not is_sgloc_picture(tmp_path / f"users.{fmt}")


def _demo(out: str, capsys) -> tuple[int, list[str]]:
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        code = main(["demo", "--objects-only", "--out", out])
    captured = capsys.readouterr()
    assert [str(w.message) for w in seen] == []
    assert "Traceback" not in captured.err
    return code, captured.err.strip().splitlines()


@pytest.mark.parametrize("fmt", ["jpg", "svg", "tif", "webp", "pdf", "png", "eps"])
def test_demo_draws_each_format_and_replaces_its_own_picture(tmp_path, monkeypatch, capsys, fmt):
    monkeypatch.chdir(tmp_path)
    assert _demo(f"maps.{fmt}", capsys) == (0, [])
    first = Path(f"maps.{fmt}").stat().st_ino
    assert _demo(f"maps.{fmt}", capsys) == (0, [])  # its own picture: replaced
    assert Path(f"maps.{fmt}").stat().st_ino != first and is_sgloc_picture(Path(f"maps.{fmt}"))
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"maps.{fmt}"]  # nothing else left


@pytest.mark.parametrize("out, made", [
    ("results/demo2/", "results/demo2/aligned_maps.png"),  # a new folder
    ("pics", "pics/aligned_maps.png"),  # an existing folder
    (".", "aligned_maps.png"),
])  # fmt: skip
def test_a_folder_gets_a_named_picture_inside(tmp_path, monkeypatch, capsys, out, made):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "pics").mkdir()
    for _ in range(2):  # the second run replaces the first's picture
        assert _demo(out, capsys) == (0, [])
        assert is_sgloc_picture(tmp_path / made)


def test_a_users_picture_is_never_replaced(tmp_path, monkeypatch, capsys):
    from PIL import Image

    monkeypatch.chdir(tmp_path)
    Image.new("RGB", (8, 8)).save("holiday.jpg")
    before = Path("holiday.jpg").read_bytes()
    code, err = _demo("holiday.jpg", capsys)
    assert code == 2 and len(err) == 1 and "was not written by sgloc" in err[0], err
    assert Path("holiday.jpg").read_bytes() == before


@pytest.mark.parametrize("out", ["maps.raw", "maps.rgba", "maps.pgf", "maps.txt", "maps"])
def test_a_format_sgloc_does_not_draw_is_one_line_naming_those_it_does(tmp_path, monkeypatch,
                                                                      capsys, out):
    monkeypatch.chdir(tmp_path)
    code, err = _demo(out, capsys)
    assert code == 2 and len(err) == 1 and err[0].startswith(f"error: {out}: "), err
    assert all(f".{fmt}" in err[0] for fmt in ("png", "jpg", "pdf", "svg"))
    assert list(tmp_path.iterdir()) == []
