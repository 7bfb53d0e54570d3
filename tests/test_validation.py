"""Every setting is checked where its typed config is built: type, range, finiteness; unknown and
ambiguous flat names are refused; errors name the setting and what is allowed."""

import math

import numpy as np
import pytest

from sgloc import SemanticGraph, localize
from sgloc.acceptance import AcceptanceConfig
from sgloc.errors import InvalidGraphError, SglocError, UnknownNameError
from sgloc.estimation import RansacConfig
from sgloc.matching.candidates import MatchingConfig
from sgloc.pipeline.config import LocalizerConfig
from sgloc.rejection import make_rejector
from sgloc.validation import MAX_VERTICES, InvalidSettingError


@pytest.mark.parametrize(
    "settings, named",
    [
        ({"ransac_threshold": math.inf}, "ransac.threshold"),
        ({"ransac_threshold": -5}, "ransac.threshold"),
        ({"ransac_threshold": "5"}, "ransac.threshold"),
        ({"eta": -0.5}, "neighbor.eta"),
        ({"eta": 1.5}, "neighbor.eta"),
        ({"tau": math.nan}, "neighbor.tau"),
        ({"top_k": -1}, "matching.top_k"),
        ({"top_k": 2.5}, "matching.top_k"),
        ({"top_k": True}, "matching.top_k"),
        ({"min_inliers": -3}, "ransac.min_inliers"),
        ({"min_confidence": 1.5}, "acceptance.min_confidence"),
        ({"min_similarity": math.nan}, "matching.min_similarity"),
        ({"descriptor": "random_walk", "n_walks": 0}, "random_walk.n_walks"),
        ({"descriptor": "random_walk", "walk_length": 25}, "random_walk.walk_length"),
        ({"scoring": "foo"}, "ransac.scoring"),
        ({"iterations": 0}, "ransac.iterations"),
        ({"ransac_confidence": 1.0}, "ransac.confidence"),
        ({"class_weights": {3: math.nan}}, "class_weights[3]"),
        ({"class_weights": {3: -1.0}}, "class_weights[3]"),
        ({"class_weights": {-2: 1.0}}, "class_weights"),
        ({"class_weights": [1, 2]}, "class_weights"),
        ({"mutual": "yes"}, "matching.mutual"),
        ({"icp": 1}, "icp"),
        ({"icp_max_distance": 0}, "icp_max_distance"),
        ({"rejection": "spectral", "sigma": -1}, "spectral.sigma"),
        ({"rejection": "clique", "n_seeds": 0}, "clique.n_seeds"),
        ({"acceptance_radius": -1}, "acceptance.radius"),
    ],
)
def test_bad_values_are_refused_with_the_setting_named(settings, named):
    with pytest.raises(InvalidSettingError, match=named.replace("[", r"\[")) as err:
        LocalizerConfig().with_overrides(**settings)
    assert "must be" in str(err.value)


@pytest.mark.parametrize("name", ["confidence", "radius", "enabled"])
def test_ambiguous_flat_names_are_refused(name):
    with pytest.raises(UnknownNameError, match="ambiguous"):
        LocalizerConfig().with_overrides(**{name: 0.5})


def test_unknown_names_are_refused():
    with pytest.raises(UnknownNameError, match="unknown setting 'weights'"):
        LocalizerConfig().with_overrides(weights=[1.0])
    with pytest.raises(UnknownNameError, match="walk_length"):  # not a histogram parameter
        LocalizerConfig().with_overrides(walk_length=3)


def test_unambiguous_spellings_route_to_their_stage():
    cfg = LocalizerConfig().with_overrides(
        ransac_threshold=2,
        threshold=3,
        ransac_confidence=0.99,
        min_confidence=0.5,
        acceptance_radius=4,
        tau=3,
        class_weights={"3": 2},
        top_k=2,
        matching_mutual=True,
    )
    assert cfg.ransac.threshold == 3.0 and cfg.ransac.confidence == 0.99
    assert cfg.acceptance.min_confidence == 0.5 and cfg.acceptance.radius == 4.0
    assert cfg.rejection_params == {"tau": 3} and cfg.class_weights == {3: 2.0}
    assert cfg.matching.top_k == 2 and cfg.matching.mutual is True


def test_stage_configs_check_themselves():
    with pytest.raises(InvalidSettingError, match="ransac.threshold"):
        RansacConfig(threshold=-1)
    with pytest.raises(InvalidSettingError, match="matching.min_similarity"):
        MatchingConfig(min_similarity=2)
    with pytest.raises(InvalidSettingError, match="acceptance.distinct_rotation"):
        AcceptanceConfig(distinct_rotation=360)
    with pytest.raises(InvalidSettingError, match="neighbor.eta"):
        make_rejector("neighbor", eta=math.inf)


def test_from_dict_checks_nested_values():
    data = LocalizerConfig().to_dict()
    data["ransac"]["iterations"] = -4
    with pytest.raises(InvalidSettingError, match="ransac.iterations"):
        LocalizerConfig.from_dict(data)
    with pytest.raises(SglocError, match="malformed"):
        LocalizerConfig.from_dict({"matching": 5})
    assert LocalizerConfig.from_dict(LocalizerConfig().to_dict()) == LocalizerConfig()


def test_yaml_config_errors_are_clean(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("ransac: [unclosed")
    with pytest.raises(SglocError, match="not a valid YAML"):
        LocalizerConfig.from_yaml(p)
    with pytest.raises(SglocError, match="is a folder"):
        LocalizerConfig.from_yaml(tmp_path)


def test_localize_api_refuses_bad_values_before_work(airsim_graphs):
    q, t = airsim_graphs
    with pytest.raises(InvalidSettingError, match="ransac.threshold"):
        localize(q, t, ransac_threshold=math.inf)


def test_vertex_limit_is_a_clear_error():
    pos = np.zeros((MAX_VERTICES + 1, 3))
    with pytest.raises(InvalidGraphError, match="limit"):
        SemanticGraph(pos, np.zeros(MAX_VERTICES + 1, int))


def _stage_configs() -> list[type]:
    from sgloc.acceptance import AcceptanceConfig, EvidenceConfig, VerificationConfig
    from sgloc.descriptors import DESCRIPTORS
    from sgloc.estimation import RansacConfig
    from sgloc.estimation.covariance import CovarianceInflation
    from sgloc.matching.candidates import MatchingConfig
    from sgloc.online import OnlineConfig
    from sgloc.online.config import OdometryNoise
    from sgloc.rejection import REJECTORS

    return [*DESCRIPTORS.values(), *REJECTORS.values(), MatchingConfig, RansacConfig,
            AcceptanceConfig, EvidenceConfig, VerificationConfig, LocalizerConfig,
            CovarianceInflation, OnlineConfig, OdometryNoise]  # fmt: skip


def test_every_stage_setting_declares_its_bounds_beside_its_field():
    import dataclasses

    from sgloc.validation import check_of

    fields = [(k, f) for k in _stage_configs() for f in dataclasses.fields(k)]
    missing = [f"{k.__name__}.{f.name}" for k, f in fields if check_of(f) is None]
    assert not missing, f"declare these settings' bounds with sgloc.validation.setting: {missing}"
    assert len(fields) > 50
    for _, f in fields:  # each check refuses what is no value at all (it is not a pass-through)
        with pytest.raises(InvalidSettingError, match=f"setting x.{f.name}\\b"):
            check_of(f)(f"x.{f.name}", object())


def test_shared_settings_are_declared_once():
    """ExtractionConfig takes its association settings from AssociationSettings (one default,
    one check), under the same names; a config cannot take a setting that is not declared."""
    import dataclasses

    from sgloc.extraction import ExtractionConfig
    from sgloc.maps.association import AssociationSettings
    from sgloc.validation import check_of, same_setting

    theirs = {f.name: f for f in dataclasses.fields(AssociationSettings)}
    ours = {f.name: f for f in dataclasses.fields(ExtractionConfig)}
    assert set(theirs) <= set(ours)
    for name, f in theirs.items():
        assert check_of(ours[name]) is check_of(f) and ours[name].default == f.default, name
    assert ExtractionConfig().association_radius == AssociationSettings().association_radius
    with pytest.raises(InvalidSettingError, match="ExtractionConfig.min_observations"):
        ExtractionConfig(min_observations=0)
    with pytest.raises(TypeError, match="no setting 'radius'"):
        same_setting(AssociationSettings, "radius")
