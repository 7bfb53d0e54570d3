"""The `paper` and `guo` presets: Guo's RANSAC against a transcription of its loop, and the
presets reachable by name from the API and the command line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sgloc import localize
from sgloc.cli import main
from sgloc.errors import UnknownNameError
from sgloc.estimation import RansacConfig, ransac
from sgloc.geometry import apply, random_rigid_transform
from sgloc.pipeline.config import LocalizerConfig
from sgloc.pipeline.presets import LOCALIZER_PRESETS, localizer_preset
from sgloc.validation import InvalidSettingError


class RecordingRng:
    """A generator that remembers every array of integers it hands out."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)
        self.calls: list[tuple[int, int, tuple, np.ndarray]] = []

    def integers(self, low, high, size):
        out = self.rng.integers(low, high, size)
        self.calls.append((low, high, np.shape(out), out))
        return out


def guo_transcribed(src, dst, samples, Td):
    """Guo's matcherRANSAC loop: per sample of 4, the Kabsch fit; count residuals < Td; a
    hypothesis replaces the best only with strictly more inliers."""
    best, max_count = None, 0
    for idx in samples:
        S, D = src[idx], dst[idx]
        cs, cd = S.mean(0), D.mean(0)
        U, _, Vt = np.linalg.svd((S - cs).T @ (D - cd))
        d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
        R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
        t = cd - R @ cs
        inliers = [i for i in range(len(src)) if np.linalg.norm(R @ src[i] + t - dst[i]) < Td]
        if len(inliers) > max_count:
            max_count, best = len(inliers), (R, t, inliers)
    return best


def _two_motions(seed: int):
    """Two groups of 5 matches, each exact under its own motion, 40 m apart: every sample from
    one group gives a model with 5 inliers, so the scoring must break ties."""
    rng = np.random.default_rng(seed)
    src = rng.uniform(-40, 40, (10, 3))
    A, B = random_rigid_transform(rng), random_rigid_transform(rng)
    dst = np.vstack([apply(A, src[:5]), apply(B, src[5:])])
    return src, dst


@pytest.mark.parametrize("seed", range(3))
def test_guo_sampler_draws_four_with_replacement_and_keeps_the_first_best(seed):
    src, dst = _two_motions(seed)
    cfg = RansacConfig(
        sampler="guo", scoring="first", confidence=None, refit_rounds=0, dof=6, max_tilt=None,
        threshold=1.0,
    )  # fmt: skip
    rec = RecordingRng(seed)
    res = ransac(src, dst, cfg, rec)
    samples = np.vstack([out for _, _, _, out in rec.calls])
    assert all(lo == 0 and hi == 10 and shape[1] == 4 for lo, hi, shape, _ in rec.calls)
    assert samples.shape == (1000, 4)  # a fixed 1000 draws, no adaptive stop
    repeats = np.array([len(set(s)) < 4 for s in samples])
    assert 0 < repeats.mean() < 1  # with replacement: some samples repeat a match
    R, t, inliers = guo_transcribed(src, dst, samples, 1.0)
    assert res.inliers.tolist() == inliers and len(inliers) == 5
    np.testing.assert_allclose(res.transform[:3, :3], R, atol=1e-8)
    np.testing.assert_allclose(res.transform[:3, 3], t, atol=1e-6)
    # A real tie: both groups were sampled pure (>= 3 distinct matches: a 5-inlier model), and
    # the winner is the group sampled pure first.
    pure = [next((k for k, s in enumerate(samples) if set(s) <= g and len(set(s)) >= 3), None)
            for g in (set(range(5)), set(range(5, 10)))]  # fmt: skip
    assert None not in pure
    assert inliers == (list(range(5)) if pure[0] < pure[1] else list(range(5, 10)))


def test_guo_inlier_rule_needs_five_and_one_percent():
    rng = np.random.default_rng(0)
    src = rng.uniform(-40, 40, (600, 3))
    T = random_rigid_transform(rng)
    outliers = rng.uniform(-300, 300, (600, 3))
    dst = outliers.copy()
    dst[:5] = apply(T, src[:5])  # 5 inliers of 600: fewer than 1 %
    cfg = RansacConfig(sampler="guo", scoring="first", confidence=None, refit_rounds=0, dof=6,
                       max_tilt=None, iterations=3000)  # fmt: skip
    res = ransac(src, dst, cfg, np.random.default_rng(1))
    assert res.transform is None and "at least 6 are needed" in res.reason  # ceil(1 % of 600)
    # 30 matches (1 % is one): 4 exact inliers are refused, 6 accepted.
    for n_in, accepted in ((4, False), (6, True)):
        sub_src, sub_dst = src[:30].copy(), outliers[:30].copy()
        sub_dst[:n_in] = apply(T, sub_src[:n_in])
        res = ransac(sub_src, sub_dst, cfg, np.random.default_rng(2))
        assert (res.transform is not None) == accepted, res.reason
        if accepted:
            assert res.inliers.tolist() == list(range(n_in))
        else:
            assert "at least 5 are needed" in res.reason


def test_guo_sampler_needs_any_rigid_motion():
    src = np.random.default_rng(0).uniform(-10, 10, (20, 3))
    with pytest.raises(InvalidSettingError, match="dof=6"):
        ransac(src, src, RansacConfig(sampler="guo", dof=4))


def test_presets_hold_the_papers_pipeline():
    paper, guo = localizer_preset("paper"), localizer_preset("guo")
    assert paper.descriptor == "histogram" and paper.rejection == "neighbor"
    assert paper.rejection_params["bound"] == "literal" and paper.rejection_params["tau"] == 5.0
    assert guo.rejection == "none"
    for cfg in (paper, guo):
        r = cfg.ransac
        assert (r.sampler, r.scoring, r.iterations, r.confidence) == ("guo", "first", 1000, None)
        assert (r.min_inliers, r.min_inlier_ratio, r.dof, r.max_tilt) == (5, 0.01, 6, None)
        assert not cfg.robust_refit and not cfg.icp and not cfg.acceptance.enabled
        assert cfg.matching.min_similarity == 0.5 and cfg.matching.top_k == 1
    assert localizer_preset("default") == LocalizerConfig()


def test_preset_by_name_in_localize(airsim_graphs):
    target, query = airsim_graphs
    res = localize(query, target, preset="paper")
    assert res.config == localizer_preset("paper").to_dict()
    assert res.accepted and len(res.matches) >= 5
    # Arguments given with the preset override it.
    res = localize(query, target, preset="guo", ransac_threshold=4.0)
    assert res.config["rejection"] == "none" and res.config["ransac"]["threshold"] == 4.0
    with pytest.raises(UnknownNameError, match="preset"):
        localize(query, target, preset="nope")


@pytest.mark.parametrize("name", ["paper", "guo"])
def test_preset_by_name_on_the_command_line(name, tmp_path, capsys):
    out = tmp_path / "r"
    assert main(["localize", "--example", "--preset", name, "--out", str(out)]) == 0
    cfg = LocalizerConfig.from_yaml(out / "config.yaml")
    assert cfg == localizer_preset(name)
    assert json.loads((out / "result.json").read_text())["accepted"]


def test_every_preset_builds():
    for name in LOCALIZER_PRESETS:
        localizer_preset(name)
    assert localizer_preset("KITTI_objects") == localizer_preset("kitti-objects")


def test_guo_sampler_keeps_the_gravity_gate():
    rng = np.random.default_rng(4)
    src = rng.uniform(-40, 40, (40, 3))
    flip = np.eye(4)
    flip[1:3, 1:3] = [[0.0, -1.0], [1.0, 0.0]]  # 90 deg about x: the up axis turned sideways
    cfg = dict(sampler="guo", scoring="first", confidence=None, refit_rounds=0, dof=6)
    assert ransac(src, apply(flip, src), RansacConfig(**cfg, max_tilt=None)).transform is not None
    res = ransac(src, apply(flip, src), RansacConfig(**cfg, max_tilt=15.0))
    assert res.transform is None and "max_tilt" in res.reason
