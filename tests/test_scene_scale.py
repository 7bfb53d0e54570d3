"""The scene scale: one unit length sets every absolute length; presets per kind of scene;
street results unchanged; the result says the scale; refusals name the setting."""

from __future__ import annotations

import numpy as np
import pytest

from sgloc import localize
from sgloc.errors import SglocError
from sgloc.geometry import transform_error
from sgloc.maps.scale import SCENES, STREET_UNIT, edge_radius, scene_hint
from sgloc.pipeline.config import LocalizerConfig
from sgloc.pipeline.presets import localizer_preset
from sgloc.sim.forest import forest_pair
from sgloc.sim.rooms import room_pair


def test_street_scale_is_the_default_config():
    base = LocalizerConfig()
    assert base.scale == STREET_UNIT and base.edge_radius == 20.0
    assert base.with_overrides(scale=STREET_UNIT) == base
    assert localizer_preset("street") == base
    # back from another scale too
    assert base.with_overrides(scale=0.5).with_overrides(scale=STREET_UNIT) == base


def test_scale_multiplies_every_length():
    cfg = LocalizerConfig().with_overrides(scale=0.5)  # a tenth of the street's
    assert cfg.scale == 0.5 and cfg.edge_radius == pytest.approx(2.0)
    assert cfg.ransac.threshold == pytest.approx(0.5)
    assert cfg.rejector_config.tau == pytest.approx(0.5)
    assert cfg.rejector_config.local_radius == pytest.approx(4.0)
    assert cfg.descriptor_config.radius == pytest.approx(4.0)
    assert cfg.icp_max_distance == pytest.approx(0.5)
    a = cfg.acceptance
    assert a.min_spread == pytest.approx(0.5) and a.distinct_translation == pytest.approx(1.0)
    assert a.evidence.small_exclusion == pytest.approx(1.0)
    assert a.verification.verify_radius == pytest.approx(0.15)
    assert a.verification.verify_density_radius == pytest.approx(1.5)
    # lengths without a unit are untouched
    assert a.distinct_rotation == LocalizerConfig().acceptance.distinct_rotation


def test_explicit_lengths_win_and_flat_settings_round_trip():
    cfg = LocalizerConfig().with_overrides(scale=1.25, tau=3.0, ransac_threshold=2.0)
    assert cfg.rejector_config.tau == 3.0 and cfg.ransac.threshold == 2.0
    assert cfg.acceptance.min_spread == pytest.approx(1.25)
    assert LocalizerConfig().with_overrides(**cfg.flat_settings()) == cfg
    assert LocalizerConfig.from_dict(cfg.to_dict()) == cfg
    # another descriptor: its own length scaled (triangles: 30 m on streets)
    tri = LocalizerConfig().with_overrides(scale=2.5, descriptor="triangles")
    assert tri.descriptor_config.radius == pytest.approx(15.0)
    hist = LocalizerConfig().with_overrides(scale=2.5, descriptor="histogram")
    assert hist.descriptor_params == {}


@pytest.mark.parametrize("bad", [0, -1.0, "big", True, float("nan")])
def test_bad_scale_is_refused_with_the_fix(bad):
    with pytest.raises(SglocError, match="scale"):
        LocalizerConfig().with_overrides(scale=bad)


def test_scene_presets_use_their_unit():
    for name in ("forest", "room"):
        cfg = localizer_preset(name)
        assert cfg.scale == SCENES[name]
        assert cfg.ransac.threshold == pytest.approx(SCENES[name])
        assert cfg.acceptance.min_spread == pytest.approx(SCENES[name])
    assert edge_radius(SCENES["room"]) == pytest.approx(2.0)


def test_room_needs_its_scale_and_the_refusal_says_so():
    pair = room_pair(np.random.default_rng(4))
    street = localize(pair.query, pair.target, seed=0)
    assert not street.accepted
    assert "preset='room'" in street.reason and "scale" in street.reason
    room = localize(pair.query, pair.target, seed=0, preset="room")
    assert room.accepted, room.reason
    te, re = transform_error(room.transform, pair.T_target_query)
    assert te < 0.5 and re < 3.0
    assert room.config["scale"] == SCENES["room"]  # the result says which scale was used


def test_forest_preset_localizes_a_one_class_pair():
    pair = forest_pair(np.random.default_rng(3))
    assert pair.shared >= 50
    res = localize(pair.query, pair.target, seed=0, preset="forest")
    assert res.accepted, res.reason
    te, re = transform_error(res.transform, pair.T_target_query)
    assert te < 1.0 and re < 3.0
    assert res.config["matching"]["top_k"] > 1


def test_no_hint_for_street_spacing():
    rng = np.random.default_rng(0)
    from sgloc.maps.graph import SemanticGraph

    street = SemanticGraph(rng.uniform(0, 300, (200, 3)) * [1, 1, 0.01], rng.integers(0, 4, 200))
    assert scene_hint(street, street, STREET_UNIT) == ""
    assert "room" in scene_hint(street.transformed(np.diag([0.05, 0.05, 1, 1])), street,
                                STREET_UNIT)  # fmt: skip


def test_cli_room_preset(tmp_path, capsys):
    from sgloc.cli import main
    from sgloc.cli.app import EXIT_NOT_LOCALIZED

    pair = room_pair(np.random.default_rng(4))
    q, t = pair.query.save(tmp_path / "q.npz"), pair.target.save(tmp_path / "t.npz")
    assert main(["localize", str(q), str(t)]) == EXIT_NOT_LOCALIZED
    err = " ".join(capsys.readouterr().err.split())
    assert "try --preset room" in err and "--set scale=auto" in err  # advice in CLI form
    out = tmp_path / "res.json"
    assert main(["localize", str(q), str(t), "--preset", "room", "--json", str(out)]) == 0
    import json

    assert json.loads(out.read_text())["accepted"]


def test_hard_case_scene_categories_split_and_truth(benchmark_module):
    hc = benchmark_module("hard_cases")
    tuning = hc.category_specs("room_pairs", quick=True)
    heldout = hc.category_specs("room_pairs", quick=True, heldout=True)
    assert {s.seed for s in tuning}.isdisjoint({s.seed for s in heldout})
    assert all(s.positive for s in tuning)
    assert not any(s.positive for s in hc.category_specs("repeated_rooms", quick=True))
    pair = hc.scene_pair(tuning[0])
    assert pair.info["shared"] > 0
    # the ground truth puts the true objects on each other (5 cm noise in each map)
    assert hc.local_residual(pair, pair.T_target_query, np.array([[0, 0]])) < 0.2
    row = hc.run_spec(tuning[0], {"scene": {}})[0]
    assert row["config"] == "scene" and row["outcome"] in ("localized", "refused", "wrong")


def test_hint_of_a_query_at_one_point_is_no_error():
    """A query whose objects all stand at one point (zero spacing) gets a refusal, not a
    math domain error from the scale hint."""
    from sgloc.maps.graph import SemanticGraph

    rng = np.random.default_rng(3)
    target = SemanticGraph(rng.uniform(0, 300, (200, 3)) * [1, 1, 0.01], rng.integers(0, 4, 200))
    point = SemanticGraph(np.zeros((12, 3)), rng.integers(0, 4, 12))
    assert isinstance(scene_hint(point, target, STREET_UNIT), str)
    result = localize(point, target)
    assert not result.accepted
