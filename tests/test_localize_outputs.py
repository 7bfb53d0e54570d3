"""`sgloc localize`: results folder, --format for piping, --config/--set/--preset, --example."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from sgloc.cli import main
from sgloc.geometry import transform_error
from sgloc.io.poses import read_kitti_poses, read_tum_poses
from sgloc.pipeline.config import LocalizerConfig


def test_example_out_folder_holds_every_form_of_one_transform(tmp_path, capsys):
    out = tmp_path / "res"
    assert main(["localize", "--example", "--out", str(out)]) == 0
    names = {p.name for p in out.iterdir()}
    assert names == {"result.json", "config.yaml", "T_target_query.txt",
                     "T_target_query_kitti.txt", "T_target_query_tum.txt", "aligned_maps.png",
                     ".sgloc-results.json"}  # the manifest: what sgloc wrote here
    text = (out / "result.json").read_text()
    res = json.loads(text)
    assert res["accepted"] and len(text.splitlines()) < 40  # compact: a matrix row a line
    T = np.array(res["T_target_query"])
    np.testing.assert_allclose(np.loadtxt(out / "T_target_query.txt"), T, atol=1e-8)
    np.testing.assert_allclose(read_kitti_poses(out / "T_target_query_kitti.txt")[0], T, atol=1e-8)
    np.testing.assert_allclose(read_tum_poses(out / "T_target_query_tum.txt")[1][0], T, atol=1e-6)
    te, re = transform_error(T, np.eye(4))  # ground truth of the shipped maps: identity
    assert te < 5.0 and re < 2.0
    cfg = LocalizerConfig.from_yaml(out / "config.yaml")
    assert cfg == LocalizerConfig()
    assert (out / "aligned_maps.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.parametrize("fmt, rows, cols", [("kitti", 1, 12), ("tum", 1, 8), ("matrix", 4, 4)])
def test_format_prints_only_the_transform(fmt, rows, cols, capsys):
    assert main(["localize", "--example", "--format", fmt]) == 0
    out = capsys.readouterr().out
    vals = np.array([[float(x) for x in ln.split()] for ln in out.strip().splitlines()])
    assert vals.shape == (rows, cols)


def test_format_json_is_the_compact_summary(capsys):
    assert main(["localize", "--example", "--format", "json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["accepted"] and np.array(d["T_target_query"]).shape == (4, 4)
    assert "matches" not in d


def test_config_set_and_preset_reach_the_localizer(tmp_path, capsys):
    LocalizerConfig().with_overrides(tau=4.0, top_k=2).to_yaml(tmp_path / "c.yaml")
    out = tmp_path / "r"
    argv = ["localize", "--example", "--out", str(out), "--config", str(tmp_path / "c.yaml"),
            "--preset", "kitti-objects", "--set", "top_k=3", "--set", "class_weights={0: 2.0}"]
    # LiDAR settings on the Airsim maps may not localize (exit 1); the folder is written anyway
    assert main(argv) in (0, 1)
    cfg = yaml.safe_load((out / "config.yaml").read_text())
    assert cfg["rejection_params"]["tau"] == 2.0  # the preset overrides the file
    assert cfg["ransac"]["threshold"] == 2.0
    assert cfg["matching"]["top_k"] == 3  # --set overrides both
    assert cfg["class_weights"] == {0: 2.0}


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["--example", "--preset", "nope"], "unknown preset"),
        (["--example", "--set", "tau"], "NAME=VALUE"),
        (["--example", "--set", "nonsense=1"], "nonsense"),
        (["--example", "--format", "xml"], "--format"),
        ([], "--example"),
    ],
)
def test_bad_options_are_one_line_exit_2(argv, needle, capsys):
    assert main(["localize", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    # one error line, after the usage line for usage errors
    assert len(err) in (1, 2) and needle in err[-1] and err[-1].startswith("error:")
    assert len(err) == 1 or err[0].startswith("Usage:")


def test_not_localized_prints_nothing_on_stdout(tmp_path, capsys):
    rng = np.random.default_rng(0)
    for name in ("a", "b"):  # two unrelated random maps
        pos = rng.uniform(0, 300, (60, 3))
        (tmp_path / f"{name}.csv").write_text(
            "x,y,z,label\n" + "".join(f"{p[0]},{p[1]},{p[2]},{i % 5}\n" for i, p in enumerate(pos))
        )
    rc = main(["localize", str(tmp_path / "a.csv"), str(tmp_path / "b.csv"), "--format", "kitti"])
    cap = capsys.readouterr()
    assert rc == 1 and cap.out == "" and "not localized" in cap.err


def test_flat_settings_round_trip():
    from sgloc.cli.options import flat_settings

    cfg = LocalizerConfig().with_overrides(
        descriptor="random_walk", n_walks=50, tau=3.0, top_k=2, ransac_threshold=2.5,
        class_weights={1: 3.0}, min_confidence=0.99, icp=True,
    )
    flat = flat_settings(cfg)
    assert flat["ransac_threshold"] == 2.5 and flat["n_walks"] == 50
    assert LocalizerConfig().with_overrides(**flat) == cfg
    assert flat_settings(LocalizerConfig()) == {}


def test_flat_yaml_config_and_experiment_preset(tmp_path, capsys):
    (tmp_path / "flat.yaml").write_text("tau: 3.5\nmin_similarity: 0.4\n")
    out = tmp_path / "r"
    argv = ["localize", "--example", "--out", str(out), "--config", str(tmp_path / "flat.yaml")]
    assert main(argv) == 0
    cfg = LocalizerConfig.from_yaml(out / "config.yaml")
    assert cfg.rejection_params["tau"] == 3.5 and cfg.matching.min_similarity == 0.4
    ex = tmp_path / "ex"
    assert main(["experiment", "table", "--dataset", "object-world", "--trials", "1",
                 "--workers", "1", "--descriptors", "fast", "--rejections", "neighbor",
                 "--preset", "city", "--config", str(tmp_path / "flat.yaml"),
                 "--out", str(ex)]) == 0
    used = yaml.safe_load((ex / "config.yaml").read_text())["experiment"]["settings"]
    assert used["tau"] == 3.5 and used["min_similarity"] == 0.4  # from the file
    assert {int(k): v for k, v in used["class_weights"].items()} == {0: 0.1}  # the preset
