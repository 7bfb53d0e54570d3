"""LocalizerConfig: typed descriptor and rejector settings, JSON and YAML in and out, configs
written before read back, one registry style."""

from __future__ import annotations

import pytest

from sgloc.cli import main
from sgloc.descriptors import HistogramDescriptor, RandomWalkDescriptor
from sgloc.errors import SglocError, UnknownNameError
from sgloc.pipeline.config import LocalizerConfig
from sgloc.rejection import NeighborRejector, SpectralRejector
from sgloc.validation import InvalidSettingError


def test_typed_stage_objects_are_stored_by_name_and_changed_fields():
    cfg = LocalizerConfig(
        descriptor=RandomWalkDescriptor(n_walks=50),
        rejection=NeighborRejector(tau=3.0, bound="literal"),
    )
    assert cfg.descriptor == "random_walk" and cfg.descriptor_params == {"n_walks": 50}
    assert cfg.rejection == "neighbor"
    assert cfg.rejection_params == {"tau": 3.0, "bound": "literal"}
    assert cfg.rejector_config == NeighborRejector(tau=3.0, bound="literal")
    assert cfg.descriptor_config == RandomWalkDescriptor(n_walks=50)
    # The same settings by name, by mapping and through with_overrides are one config.
    by_name = LocalizerConfig(
        descriptor="Random-Walk", descriptor_params={"n_walks": 50},
        rejection="neighbor", rejection_params={"tau": 3.0, "bound": "literal"},
    )  # fmt: skip
    by_map = LocalizerConfig(
        descriptor={"name": "random_walk", "n_walks": 50},
        rejection={"name": "neighbor", "tau": 3.0, "bound": "literal"},
    )
    flat = LocalizerConfig().with_overrides(
        descriptor=RandomWalkDescriptor(n_walks=50), rejection=NeighborRejector(tau=3.0),
        bound="literal",
    )  # fmt: skip
    assert cfg == by_name == by_map == flat
    assert LocalizerConfig(descriptor=HistogramDescriptor()) == LocalizerConfig(
        descriptor="histogram"
    )


def test_typed_stage_values_are_checked():
    with pytest.raises(InvalidSettingError, match="bound"):
        LocalizerConfig(rejection={"name": "neighbor", "bound": "loose"})
    with pytest.raises(UnknownNameError, match="descriptor"):
        LocalizerConfig(descriptor={"name": "nope"})
    with pytest.raises(UnknownNameError):
        LocalizerConfig(rejection="spectral", rejection_params={"bound": "literal"})
    with pytest.raises(SglocError, match="name"):
        LocalizerConfig(rejection={"tau": 3.0})


@pytest.mark.parametrize("suffix", [".json", ".yaml"])
def test_json_and_yaml_round_trip(tmp_path, suffix):
    cfg = LocalizerConfig(rejection=SpectralRejector(sigma=2.0)).with_overrides(
        class_weights={0: 0.1, 3: 2.0}, dof=6, max_tilt=None, sampler="guo", scoring="first",
        acceptance=False, class_scale=True,
    )  # fmt: skip
    path = tmp_path / f"c{suffix}"
    cfg.save(path)
    assert LocalizerConfig.load(path) == cfg


def test_json_config_reaches_the_command_line(tmp_path):
    path = tmp_path / "c.json"
    LocalizerConfig().with_overrides(tau=3.0, top_k=2).save(path)
    out = tmp_path / "r"
    assert main(["localize", "--example", "--config", str(path), "--out", str(out)]) in (0, 1)
    cfg = LocalizerConfig.from_yaml(out / "config.yaml")
    assert cfg.rejection_params["tau"] == 3.0 and cfg.matching.top_k == 2


def test_dicts_written_before_are_read():
    # The oldest layout: no acceptance, no class_scale, the histogram default of the time.
    old = {
        "descriptor": "histogram", "descriptor_params": {},
        "matching": {"min_similarity": 0.5, "top_k": 1, "mutual": False},
        "rejection": "neighbor", "rejection_params": {"tau": 5.0, "eta": 0.5},
        "ransac": {"threshold": 5.0, "iterations": 1000, "min_inliers": 5,
                   "min_inlier_ratio": 0.01, "scoring": "count"},
        "class_weights": None, "robust_refit": True, "icp": False, "icp_max_distance": 2.0,
    }  # fmt: skip
    cfg = LocalizerConfig.from_dict(old)
    assert cfg.descriptor == "histogram" and cfg.rejector_config == NeighborRejector()
    assert cfg.ransac.scoring == "count" and cfg.acceptance.enabled
    assert LocalizerConfig.from_dict(cfg.to_dict()) == cfg
    now = LocalizerConfig().to_dict()
    assert set(now) >= set(old) and now["rejection"] == "neighbor"  # the same layout


def test_one_registry_style_for_names():
    from sgloc.datasets import DATASETS
    from sgloc.datasets.downloads import DOWNLOADS
    from sgloc.descriptors import DESCRIPTORS
    from sgloc.evaluation.scenes import PAIR_SOURCES
    from sgloc.pipeline.presets import EXTRACTION_PRESETS, LOCALIZER_PRESETS
    from sgloc.registry import Registry
    from sgloc.rejection import REJECTORS

    tables = (DESCRIPTORS, REJECTORS, DATASETS, PAIR_SOURCES, LOCALIZER_PRESETS,
              EXTRACTION_PRESETS, DOWNLOADS)  # fmt: skip
    assert all(isinstance(t, Registry) for t in tables)
    assert DESCRIPTORS.lookup("Random-Walk") is RandomWalkDescriptor
    assert REJECTORS.lookup(" NEIGHBOR ") is NeighborRejector
    assert DATASETS.lookup("kitti-objects") is DATASETS["kitti_objects"]
    assert LOCALIZER_PRESETS.lookup("kitti_objects") is LOCALIZER_PRESETS["kitti-objects"]
    assert PAIR_SOURCES.lookup("Synthetic") is PAIR_SOURCES["city"]  # an alias
    with pytest.raises(UnknownNameError, match="choose one of"):
        LOCALIZER_PRESETS.lookup("nope")
    with pytest.raises(UnknownNameError, match=r"did you mean random_walk\?"):
        DESCRIPTORS.lookup("random_wlak")


def test_acceptance_uses_the_consistency_layer_not_rejection():
    import ast
    from pathlib import Path

    import sgloc.acceptance

    imported = set()
    for path in Path(sgloc.acceptance.__file__).parent.glob("*.py"):
        tree = ast.parse(path.read_text())
        imported |= {
            node.module
            for node in ast.walk(tree)
            if isinstance(node, ast.ImportFrom) and node.module
        }
    assert "sgloc.consistency.pairwise" in imported
    assert not any(m.startswith("sgloc.rejection") for m in imported)


@pytest.mark.parametrize("preset", ["paper", "guo", "kitti-objects", "city", "default"])
def test_flat_settings_round_trip(preset):
    from sgloc.pipeline.presets import localizer_preset

    cfg = localizer_preset(preset).with_overrides(
        descriptor_radius=40.0, class_scale=True, matching_max_ratio=0.9
    ) if preset == "default" else localizer_preset(preset)  # fmt: skip
    assert LocalizerConfig().with_overrides(**cfg.flat_settings()) == cfg


def test_descriptor_radius_has_a_qualified_name():
    cfg = LocalizerConfig().with_overrides(descriptor_radius=40.0, rejection_tau=3.0)
    assert cfg.descriptor_params == {"radius": 40.0} and cfg.rejection_params == {"tau": 3.0}
    with pytest.raises(UnknownNameError, match="descriptor_radius"):
        LocalizerConfig().with_overrides(radius=40.0)


def test_saved_preset_config_reaches_the_command_line(tmp_path):
    from sgloc.pipeline.presets import localizer_preset

    path = tmp_path / "paper.yaml"
    localizer_preset("paper").save(path)
    out = tmp_path / "r"
    assert main(["localize", "--example", "--config", str(path), "--out", str(out)]) == 0
    assert LocalizerConfig.from_yaml(out / "config.yaml") == localizer_preset("paper")


def test_class_scale_values():
    assert LocalizerConfig().class_scale == "none"
    assert LocalizerConfig(class_scale=True).class_scale == "full"
    assert LocalizerConfig(class_scale=False).class_scale == "none"
    cfg = LocalizerConfig().with_overrides(class_scale="height")
    assert cfg.class_scale == "height" and cfg.flat_settings() == {"class_scale": "height"}
    assert LocalizerConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(InvalidSettingError, match="class_scale"):
        LocalizerConfig(class_scale="xy")


def test_one_settings_file_reader_for_configs_and_the_cli(tmp_path):
    from sgloc.cli.options import read_settings_file

    cfg = LocalizerConfig().with_overrides(tau=3.0, class_weights={0: 0.5})
    for name in ("c.json", "c.yaml"):
        cfg.save(tmp_path / name)
        assert LocalizerConfig.load(tmp_path / name) == cfg
        assert read_settings_file(tmp_path / name) == {"tau": 3.0, "class_weights": {0: 0.5}}
    (tmp_path / "bad.json").write_text("{tau: 3")
    for read in (LocalizerConfig.load, read_settings_file):
        with pytest.raises(SglocError, match="not a valid JSON config"):
            read(tmp_path / "bad.json")
        with pytest.raises(SglocError, match="missing.yaml"):
            read(tmp_path / "missing.yaml")
