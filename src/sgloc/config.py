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
from sgloc.validation import validate_localizer_settings


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
        validate_localizer_settings(self)  # type and range of the top-level settings
        # Fail early on unknown names or parameters.
        make_descriptor(self.descriptor, **self.descriptor_params)
        make_rejector(self.rejection, **self.rejection_params)

    def with_overrides(self, **overrides: Any) -> LocalizerConfig:
        """A copy with flat settings routed to their stage, e.g. `tau=3, min_similarity=0.6`.

        A bare name must belong to one stage only; `ransac_<field>`, `matching_<field>` and
        `acceptance_<field>` name a stage's field explicitly. Names that would be read two ways
        (FLAT_AMBIGUOUS, e.g. `confidence`) and unknown names raise UnknownNameError. Every value
        is checked by the stage config it lands in (sgloc.validation).
        """
        overrides = dict(overrides)
        top = {k: overrides.pop(k) for k in ("descriptor", "rejection") if k in overrides}
        descriptor = top.get("descriptor", self.descriptor)
        rejection = top.get("rejection", self.rejection)
        # A new descriptor or rejector starts from its own defaults.
        params = {
            "descriptor_params": {} if "descriptor" in top else dict(self.descriptor_params),
            "rejection_params": {} if "rejection" in top else dict(self.rejection_params),
        }
        stages: dict[str, dict[str, Any]] = {"matching": {}, "ransac": {}, "acceptance": {}}
        acceptance = _acceptance(overrides.pop("acceptance")) if "acceptance" in overrides else None
        routes = _flat_routes(descriptor, rejection)
        for key, value in overrides.items():
            where, name = _route(key, routes, descriptor, rejection)
            if where in stages:
                stages[where][name] = value
            elif where in params:
                params[where][name] = value
            else:
                top[name] = value
        try:
            return dataclasses.replace(
                self,
                **top,
                **params,
                matching=dataclasses.replace(self.matching, **stages["matching"]),
                ransac=dataclasses.replace(self.ransac, **stages["ransac"]),
                acceptance=dataclasses.replace(
                    acceptance or self.acceptance, **stages["acceptance"]
                ),
            )
        except TypeError as e:  # a descriptor/rejector given a parameter it does not have
            raise UnknownNameError(f"unknown setting: {e}") from None

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> LocalizerConfig:
        """The config of a nested dict (as `to_dict` writes it); every value is checked."""
        if not isinstance(data, dict):
            raise SglocError(f"malformed localizer config: expected a mapping, got {data!r:.60}.")
        data = dict(data)
        try:
            for key, klass in (("matching", MatchingConfig), ("ransac", RansacConfig)):
                sub = data.get(key) or {}
                if not isinstance(sub, dict):
                    raise SglocError(f"malformed localizer config: {key!r} must be a mapping.")
                data[key] = klass(**sub)
            data["acceptance"] = _acceptance(data.get("acceptance", {}))
            return cls(**data)
        except TypeError as e:
            raise SglocError(f"malformed localizer config: {e}") from None

    def to_yaml(self, path: str | Path) -> None:
        Path(path).write_text(yaml.safe_dump(self.to_dict(), sort_keys=False))

    @classmethod
    def from_yaml(cls, path: str | Path) -> LocalizerConfig:
        from sgloc.io.files import MAX_TEXT_FILE_BYTES, read_regular_file

        raw = read_regular_file(path, "YAML config file", MAX_TEXT_FILE_BYTES, SglocError)
        try:
            data = yaml.safe_load(raw.decode("utf-8"))
        except (yaml.YAMLError, UnicodeDecodeError, RecursionError) as e:
            raise SglocError(f"{path}: not a valid YAML config ({type(e).__name__}).") from None
        return cls.from_dict(data or {})


def _acceptance(value: Any) -> AcceptanceConfig:
    """An AcceptanceConfig from itself, a dict, or a bool (False switches the test off)."""
    if isinstance(value, AcceptanceConfig):
        return value
    if isinstance(value, bool):
        return AcceptanceConfig(enabled=value)
    if value is not None and not isinstance(value, dict):
        raise SglocError(
            f"setting acceptance={value!r}: give True/False or a mapping of its fields."
        )
    try:
        return AcceptanceConfig(**(value or {}))
    except TypeError as e:
        raise UnknownNameError(f"setting acceptance: {e}") from None


#: Flat names that would be read two ways, with the spellings to use instead.
FLAT_AMBIGUOUS = {
    "confidence": "ransac_confidence (RANSAC's stop probability) or min_confidence (the "
    "acceptance test's strictness)",
    "radius": "acceptance_radius (the acceptance test's inlier radius; the graph edge radius is "
    "set when a graph is built or loaded)",
    "enabled": "acceptance_enabled or acceptance=False",
}
_TOP_LEVEL = {"class_weights", "robust_refit", "icp", "icp_max_distance"}


def _flat_routes(descriptor: Any, rejection: Any) -> dict[str, list[tuple[str, str]]]:
    """{flat name: [(stage, field), ...]} of every bare and stage-qualified setting name."""
    desc = DESCRIPTORS.get(descriptor.replace("-", "_")) if isinstance(descriptor, str) else None
    rej = REJECTORS.get(rejection) if isinstance(rejection, str) else None
    stages = {
        "matching": _fields(MatchingConfig),
        "ransac": _fields(RansacConfig),
        "acceptance": _fields(AcceptanceConfig),
        "descriptor_params": _fields(desc) if desc else set(),
        "rejection_params": _fields(rej) if rej else set(),
        "top": _TOP_LEVEL,
    }
    routes: dict[str, list[tuple[str, str]]] = {}
    for stage, names in stages.items():
        for name in names:
            routes.setdefault(name, []).append((stage, name))
            if stage in ("matching", "ransac", "acceptance"):
                routes.setdefault(f"{stage}_{name}", []).append((stage, name))
    return routes


def _route(
    key: str, routes: dict[str, list[tuple[str, str]]], descriptor: Any, rejection: Any
) -> tuple[str, str]:
    if key in FLAT_AMBIGUOUS:
        raise UnknownNameError(f"setting {key!r} is ambiguous; use {FLAT_AMBIGUOUS[key]}.")
    found = routes.get(key, [])
    if len(found) == 1:
        return found[0]
    if found:
        options = ", ".join(
            f"{s}_{n}" if s in ("matching", "ransac", "acceptance") else f"{s}={{{n!r}: ...}}"
            for s, n in found
        )
        raise UnknownNameError(f"setting {key!r} is ambiguous; use one of {options}.")
    raise UnknownNameError(
        f"unknown setting {key!r} for descriptor {descriptor!r} and rejection {rejection!r}; "
        "see LocalizerConfig and the stage configs."
    )


def _fields(klass: type | None) -> set[str]:
    return {f.name for f in dataclasses.fields(klass)} if klass is not None else set()
