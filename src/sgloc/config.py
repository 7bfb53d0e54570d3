"""LocalizerConfig: every setting of the pipeline in one typed, serialisable object."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from sgloc.acceptance import AcceptanceConfig
from sgloc.descriptors import DESCRIPTORS, make_descriptor
from sgloc.errors import SglocError, UnknownNameError
from sgloc.estimation import RansacConfig
from sgloc.matching import MatchingConfig
from sgloc.rejection import REJECTORS, make_rejector


@dataclass
class LocalizerConfig:
    """Settings of `localize`. Defaults: the paper's, except the descriptor
    (`distance_histogram`) and the ground-vehicle motion model of `RansacConfig` (dof=4,
    max_tilt=15), chosen by measurement (docs/acceptance.md, the hard-cases benchmark).

    descriptor / descriptor_params: name in DESCRIPTORS and its parameters.
    rejection / rejection_params: name in REJECTORS and its parameters.
    class_weights: {class id: weight} for the final weighted fit (others weigh 1).
    robust_refit: refine the final fit over RANSAC's inliers by an M-estimator (Tukey biweight
        IRLS, `sgloc.estimation.irls_refine`); False: the plain weighted least squares of Eq. 4.
    class_scale: in the robust refit, weigh each class by the inverse variance of its own
        residuals (`sgloc.estimation.class_precision`), so that objects whose centre moves with
        the viewpoint count less.
    icp: refine the final transform by mutual-nearest-neighbour ICP on all objects of the two
        graphs (not in the paper's pipeline; see docs/core_benchmark.md for its effect).
    icp_max_distance: ICP pairing radius (metres).
    acceptance: the test behind `success` (sgloc.acceptance; strictness = min_confidence).
    """

    descriptor: str = "distance_histogram"
    descriptor_params: dict[str, Any] = field(default_factory=dict)
    matching: MatchingConfig = field(default_factory=MatchingConfig)
    rejection: str = "neighbor"
    rejection_params: dict[str, Any] = field(default_factory=dict)
    ransac: RansacConfig = field(default_factory=RansacConfig)
    class_weights: dict[int, float] | None = None
    robust_refit: bool = True
    class_scale: bool = False
    icp: bool = False
    icp_max_distance: float = 5.0
    acceptance: AcceptanceConfig = field(default_factory=AcceptanceConfig)

    def __post_init__(self) -> None:
        # Fail early on unknown names or parameters.
        make_descriptor(self.descriptor, **self.descriptor_params)
        make_rejector(self.rejection, **self.rejection_params)

    def with_overrides(self, **overrides: Any) -> LocalizerConfig:
        """A copy with flat settings routed to their stage, e.g. `tau=3, min_similarity=0.6`."""
        cfg = dataclasses.replace(
            self,
            descriptor_params=dict(self.descriptor_params),
            rejection_params=dict(self.rejection_params),
            matching=dataclasses.replace(self.matching),
            ransac=dataclasses.replace(self.ransac),
            acceptance=dataclasses.replace(self.acceptance),
        )
        if "descriptor" in overrides:
            cfg.descriptor = overrides.pop("descriptor")
            cfg.descriptor_params = {}
        if "rejection" in overrides:
            cfg.rejection = overrides.pop("rejection")
            cfg.rejection_params = {}
        if "ransac_threshold" in overrides:
            overrides["threshold"] = overrides.pop("ransac_threshold")
        desc_fields = _fields(DESCRIPTORS.get(cfg.descriptor.replace("-", "_")))
        rej_fields = _fields(REJECTORS.get(cfg.rejection))
        for key, value in overrides.items():
            if key in _fields(MatchingConfig):
                setattr(cfg.matching, key, value)
            elif key in _fields(RansacConfig):
                setattr(cfg.ransac, key, value)
            elif key in desc_fields:
                cfg.descriptor_params[key] = value
            elif key in rej_fields:
                cfg.rejection_params[key] = value
            elif key in _fields(AcceptanceConfig) and key not in {"enabled", "radius"}:
                cfg.acceptance = dataclasses.replace(cfg.acceptance, **{key: value})
            elif key == "acceptance":
                cfg.acceptance = _acceptance(value)
            elif key in {"class_weights", "robust_refit", "class_scale", "icp", "icp_max_distance"}:
                setattr(cfg, key, value)
            else:
                raise UnknownNameError(
                    f"unknown setting {key!r} for descriptor {cfg.descriptor!r} and rejection "
                    f"{cfg.rejection!r}; see LocalizerConfig and the stage configs."
                )
        cfg.__post_init__()
        return cfg

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> LocalizerConfig:
        data = dict(data)
        try:
            data["matching"] = MatchingConfig(**data.get("matching", {}))
            data["ransac"] = RansacConfig(**data.get("ransac", {}))
            data["acceptance"] = _acceptance(data.get("acceptance", {}))
            return cls(**data)
        except TypeError as e:
            raise SglocError(f"malformed localizer config: {e}") from e

    def to_yaml(self, path: str | Path) -> None:
        Path(path).write_text(yaml.safe_dump(self.to_dict(), sort_keys=False))

    @classmethod
    def from_yaml(cls, path: str | Path) -> LocalizerConfig:
        p = Path(path)
        if not p.exists():
            raise SglocError(f"{p}: no such config file.")
        return cls.from_dict(yaml.safe_load(p.read_text()) or {})


def _acceptance(value: Any) -> AcceptanceConfig:
    """An AcceptanceConfig from itself, a dict, or a bool (False switches the test off)."""
    if isinstance(value, AcceptanceConfig):
        return value
    if isinstance(value, bool):
        return AcceptanceConfig(enabled=value)
    return AcceptanceConfig(**(value or {}))


def _fields(klass: type | None) -> set[str]:
    return {f.name for f in dataclasses.fields(klass)} if klass is not None else set()
