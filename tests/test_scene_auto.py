"""scale="auto": the scene scale estimated from the target map, said in the result; and the
room preset's check of the other places where a floor repeats itself (identical offices)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sgloc import localize, prepare
from sgloc.acceptance.places import check_other_places
from sgloc.datasets.downloads import airsim_guo
from sgloc.errors import SglocError
from sgloc.estimation import GROUND_VEHICLE
from sgloc.io.results import summary
from sgloc.maps.graph import SemanticGraph
from sgloc.maps.scale import SCENES, estimate_scale
from sgloc.pipeline.config import LocalizerConfig
from sgloc.pipeline.presets import localizer_preset
from sgloc.sim.forest import forest_pair
from sgloc.sim.rooms import repeated_room_pair, room_pair


def test_estimate_names_the_scene_of_each_kind_of_map():
    room = room_pair(np.random.default_rng(4)).target
    forest = forest_pair(np.random.default_rng(3)).target
    street = airsim_guo()[1]
    assert estimate_scale(room).scene == "room" and estimate_scale(room).unit == SCENES["room"]
    assert estimate_scale(forest).scene == "forest"
    est = estimate_scale(street)
    assert est.scene == "street" and est.unit == SCENES["street"]
    assert 3.2 < est.spacing < 8 and est.extent > 100


def test_a_map_smaller_than_its_scene_steps_down():
    # street spacing (5 m apart) but only 20 m across: too small for 8 street units (40 m)
    xy = np.stack(np.meshgrid(np.arange(5) * 5.0, np.arange(5) * 5.0), -1).reshape(-1, 2)
    g = SemanticGraph(np.column_stack([xy, np.zeros(len(xy))]), np.arange(len(xy)) % 3)
    est = estimate_scale(g)
    assert est.spacing == pytest.approx(5.0) and est.scene == "forest"


def test_degenerate_map_is_a_clear_error():
    g = SemanticGraph(np.zeros((4, 3)), np.zeros(4, dtype=int), name="dots")
    with pytest.raises(SglocError, match="dots"):
        estimate_scale(g)


def test_auto_resolves_to_the_scaled_config_and_explicit_lengths_win():
    auto = LocalizerConfig().with_overrides(scale="auto")
    assert auto.scale == "auto" and auto.edge_radius == 20.0
    assert LocalizerConfig.from_dict(auto.to_dict()) == auto  # saved and read back
    assert LocalizerConfig().with_overrides(**auto.flat_settings()) == auto
    assert auto.resolved(5.0) == LocalizerConfig()
    assert auto.resolved(0.5) == LocalizerConfig().with_overrides(scale=0.5)
    mine = LocalizerConfig().with_overrides(scale="auto", min_spread=1.0, ransac_threshold=0.3)
    r = mine.resolved(0.5)
    assert r.acceptance.min_spread == 1.0 and r.ransac.threshold == 0.3
    assert r.acceptance.verification.verify_radius == pytest.approx(0.15)  # scaled
    assert LocalizerConfig().with_overrides(scale=2.0).resolved(0.5).scale == 2.0
    with pytest.raises(SglocError, match="auto"):
        LocalizerConfig(scale="big")


def test_auto_localizes_a_room_and_says_how():
    pair = room_pair(np.random.default_rng(4))
    res = localize(pair.query, pair.target, scale="auto")
    assert res.accepted, res.reason
    assert res.config["scale"] == SCENES["room"]
    assert res.scale_estimate is not None and res.scale_estimate.scene == "room"
    doc = summary(res)["scale"]
    assert doc["estimated"] and doc["unit_m"] == SCENES["room"] and doc["scene"] == "room"
    given = localize(pair.query, pair.target, preset="room")
    assert summary(given)["scale"] == {"unit_m": SCENES["room"], "estimated": False}
    assert given.scale_estimate is None


def test_auto_on_a_street_map_is_the_default_result_bit_for_bit():
    q, t = airsim_guo()
    auto, default = localize(q, t, scale="auto"), localize(q, t)
    assert auto.scale_estimate.scene == "street"
    assert np.array_equal(auto.transform, default.transform)
    assert auto.confidence == default.confidence
    assert np.array_equal(auto.matches, default.matches)
    assert auto.config == default.config


def test_prepared_map_keeps_its_estimate_and_gives_the_same_result():
    pair = room_pair(np.random.default_rng(4))
    cfg = LocalizerConfig().with_overrides(scale="auto")
    prepared = prepare(pair.target, cfg)
    assert prepared.scale_estimate.scene == "room" and prepared.config.scale == SCENES["room"]
    a = localize(pair.query, prepared, config=cfg)
    b = localize(pair.query, pair.target, config=cfg)
    assert a.accepted and np.array_equal(a.transform, b.transform)
    assert a.scale_estimate == b.scale_estimate


def test_cli_says_the_estimated_scale(tmp_path, capsys):
    from sgloc.cli import main

    pair = room_pair(np.random.default_rng(4))
    q, t = pair.query.save(tmp_path / "q.npz"), pair.target.save(tmp_path / "t.npz")
    out = tmp_path / "res.json"
    assert main(["localize", str(q), str(t), "--set", "scale=auto", "--json", str(out)]) == 0
    assert "estimated from the target map: room" in " ".join(capsys.readouterr().out.split())
    doc = json.loads(out.read_text())
    assert doc["scale"]["estimated"] and doc["config"]["scale"] == SCENES["room"]
    folder = tmp_path / "res"
    assert main(["localize", str(q), str(t), "--set", "scale=auto", "--out", str(folder)]) == 0
    assert LocalizerConfig.load(folder / "config.yaml") == localizer_preset("room")
    assert main(["localize", str(q), str(t), "--preset", "room"]) == 0
    assert "scene scale 0.5 m (given)" in capsys.readouterr().out


def _twins(rng: np.random.Generator, copies: int) -> tuple[SemanticGraph, SemanticGraph]:
    """A 10 m x 8 m layout of 30 objects (query) and a target of `copies` copies of it 12 m
    apart along x, each with its own 5 cm noise and one object in ten missing."""
    pos = np.column_stack([rng.uniform(0, 10, 30), rng.uniform(0, 8, 30), np.zeros(30)])
    lab = rng.integers(0, 5, 30)
    parts = [(pos + [12.0 * k, 0, 0] + rng.normal(0, 0.05, pos.shape), lab)
             for k in range(copies)]  # fmt: skip
    keep = [rng.random(30) >= 0.1 for _ in parts]
    target = SemanticGraph(np.concatenate([p[m] for (p, _), m in zip(parts, keep, strict=True)]),
                           np.concatenate([la[m] for (_, la), m in zip(parts, keep,
                                                                        strict=True)]))  # fmt: skip
    query = SemanticGraph(pos + rng.normal(0, 0.05, pos.shape), lab)
    return query, target


def test_other_places_weigh_a_twin_about_as_much_as_the_estimate():
    rng = np.random.default_rng(0)
    query, target = _twins(rng, 3)
    check = check_other_places(query, target, np.eye(4), 0.5, 0.25, (1.0, 40.0, 8),
                               GROUND_VEHICLE)  # fmt: skip
    assert check.places >= 1 and min(abs(check.shift - 12.0), abs(check.shift - 24.0)) < 0.5
    assert check.log10_p > -1.0  # a near tie: the place cannot be told
    alone, single = _twins(np.random.default_rng(0), 1)
    check = check_other_places(alone, single, np.eye(4), 0.5, 0.25, (1.0, 40.0, 8),
                               GROUND_VEHICLE)  # fmt: skip
    assert check.log10_p == -np.inf or check.log10_p < -4.0


@pytest.mark.parametrize("seed", [1, 3, 6])
def test_room_preset_refuses_an_office_of_identical_offices(seed):
    pair = repeated_room_pair(np.random.default_rng(seed))
    without = localize(pair.query, pair.target, preset="room", other_places=0)
    assert without.accepted  # these three fooled the test before the check
    res = localize(pair.query, pair.target, preset="room")
    assert not res.accepted and "fits as well" in res.reason and "other_places=0" in res.reason


def test_room_preset_still_localizes_rooms():
    ok = [localize(p.query, p.target, preset="room").accepted
          for p in (room_pair(np.random.default_rng(s)) for s in (0, 1, 2, 3))]  # fmt: skip
    assert all(ok)


def test_copy_weight_is_the_sign_test_and_places_take_the_larger():
    from sgloc.acceptance.places import log10_copy_weight, place_weights

    lg = log10_copy_weight(np.array([0, 2, 4, 13]), np.array([0, 2, 0, 1]))
    assert lg[0] == 0.0 and lg[1] == pytest.approx(0.0)  # nothing to tell / a tie
    assert lg[2] == pytest.approx(np.log10(1 / 16))  # 4 heads of 4 fair coins
    assert lg[3] == pytest.approx(np.log10((15 / 16384) / (1 - 1 / 16384)))  # / P(X >= 1)
    # a copy (lands 43 of the estimate's 46) weighs as a copy, not as chance
    w = place_weights(46, np.array([3, 13]), np.array([0, 1]), np.array([43, 4]))
    assert w[0] == pytest.approx(np.log10(1 / 8)) and w[1] < -8


def test_hard_case_docs_keep_the_other_sections(benchmark_module):
    hc = benchmark_module("hard_cases")
    doc = "# Hard cases\nheader\n" + "".join(
        f"## Results: {hc.SECTION_TITLES[t]}\n\n{t} table\n" for t in ("tuning", "heldout",
                                                                       "scenes-tuning"))
    sections = hc.doc_sections(doc)
    assert list(sections) == ["tuning", "heldout", "scenes-tuning"]
    assert "heldout table" in sections["heldout"] and "tuning table" not in sections["heldout"]
    assert "header" not in "".join(sections.values())


def test_auto_takes_the_estimated_scene_preset_and_explicit_settings_win():
    from sgloc.maps.scale import ScaleEstimate
    from sgloc.pipeline.presets import at_estimated_scale, localizer_preset

    auto = LocalizerConfig().with_overrides(scale="auto")
    for scene in ("street", "forest", "room"):
        est = ScaleEstimate(SCENES[scene], scene, 1.0, 100.0)
        assert at_estimated_scale(auto, est) == localizer_preset(scene)
    mine = LocalizerConfig().with_overrides(scale="auto", top_k=2, other_places=3)
    forest = at_estimated_scale(mine, ScaleEstimate(SCENES["forest"], "forest", 2.0, 200.0))
    assert forest.matching.top_k == 2 and forest.acceptance.other_places == 3
    assert forest.descriptor_params == {"radius": 20.0}  # the preset's, not given


def test_auto_refuses_an_office_of_identical_offices():
    pair = repeated_room_pair(np.random.default_rng(1))
    res = localize(pair.query, pair.target, scale="auto")
    assert not res.accepted and "fits as well" in res.reason
    assert res.settings.acceptance.other_places == 8  # the room preset's check came with it
