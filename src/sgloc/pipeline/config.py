"""LocalizerConfig: every setting of the pipeline in one typed, serialisable object."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sgloc.acceptance import AcceptanceConfig, EvidenceConfig, VerificationConfig
from sgloc.descriptors import DESCRIPTORS, Descriptor, make_descriptor
from sgloc.errors import SglocError, UnknownNameError
from sgloc.estimation import MotionModel, RansacConfig
from sgloc.io.settings_file import read_settings_data, write_settings_data
from sgloc.maps.scale import AUTO, STREET_UNIT, check_scale
from sgloc.maps.scale import edge_radius as scene_edge_radius
from sgloc.maps.scale import factor as scale_factor
from sgloc.matching.candidates import MatchingConfig
from sgloc.registry import Registry
from sgloc.rejection import REJECTORS, Rejector, make_rejector
from sgloc.validation import (
    MAX_COORDINATE,
    InvalidSettingError,
    check_class_scale,
    check_class_weights,
    flag,
    group,
    parameters,
    real,
    setting,
    stage_name,
    validate_settings,
)

#: ICP's default pairing radius (m), the street value `scale` multiplies.
_DEFAULT_ICP_DISTANCE = 5.0
#: Fields of descriptors and rejectors that are lengths in metres (`scale` multiplies them).
_STAGE_LENGTHS = {"radius", "tau", "local_radius", "sigma"}


@dataclass
class LocalizerConfig:
    """Settings of `localize`. Defaults: the paper's, except the descriptor
    (`distance_histogram`) and the ground-vehicle motion model of `RansacConfig` (dof=4,
    max_tilt=15), chosen by measurement (docs/acceptance.md, the hard-cases benchmark).

    descriptor / descriptor_params: name in DESCRIPTORS and its parameters. `descriptor` may
        also be given typed, as the descriptor itself (`HistogramDescriptor()`) or as a mapping
        {"name": ..., field: value}; it is stored as its registered name and the fields that
        differ from the descriptor's defaults. `descriptor_config` is the typed object.
    rejection / rejection_params: the same for the rejector (REJECTORS; `rejector_config`).
    class_weights: {class id: weight} for the final weighted fit (others weigh 1).
    robust_refit: refine the final fit over RANSAC's inliers by an M-estimator (Tukey biweight
        IRLS, `sgloc.estimation.irls_refine`); False: the plain weighted least squares of Eq. 4.
    class_scale: in the robust refit, weigh each class by the inverse variance of its own
        residuals (`sgloc.estimation.class_scales`), so that objects whose centre moves with
        the viewpoint count less: "none"; "height" (per class vertical scales, one horizontal
        scale for all); "full" (per class horizontal and vertical scales). False and True
        are read as "none" and "full".
    icp: refine the final transform by mutual-nearest-neighbour ICP on all objects of the two
        graphs (not in the paper's pipeline; see docs/core_benchmark.md for its effect).
    icp_max_distance: ICP pairing radius (metres).
    acceptance: the test behind `success` (sgloc.acceptance; strictness = min_confidence),
        with its `evidence` and `verification` groups (their fields keep their flat names).
    scale: metres, the scene's unit length (`sgloc.maps.scale`; street maps 5 m, the default).
        Setting it through `with_overrides` (`localize(..., scale=...)`, the `forest` and
        `room` presets) sets every absolute length of the stages to its street default times
        scale / 5 m, except the lengths given explicitly; the config records the scale used.
        "auto": the scale of the target map (`sgloc.maps.scale.estimate_scale`), estimated by each
        localization (`resolved` gives the config of an estimated scale); the result's config
        holds the scale used and `LocalizationResult.scale_estimate` how it was estimated.
    """

    descriptor: str | Descriptor | dict[str, Any] = setting(
        "distance_histogram", check=stage_name
    )
    descriptor_params: dict[str, Any] = setting(default_factory=dict, check=parameters)
    matching: MatchingConfig = setting(default_factory=MatchingConfig, check=group(MatchingConfig))
    rejection: str | Rejector | dict[str, Any] = setting("neighbor", check=stage_name)
    rejection_params: dict[str, Any] = setting(default_factory=dict, check=parameters)
    ransac: RansacConfig = setting(default_factory=RansacConfig, check=group(RansacConfig))
    class_weights: dict[int, float] | None = setting(None, check=check_class_weights)
    robust_refit: bool = setting(True, check=flag())
    class_scale: bool | str = setting("none", check=check_class_scale)
    icp: bool = setting(False, check=flag())
    icp_max_distance: float = setting(
        _DEFAULT_ICP_DISTANCE, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m")
    )
    acceptance: AcceptanceConfig = setting(
        default_factory=AcceptanceConfig, check=group(AcceptanceConfig)
    )
    scale: float | str = setting(STREET_UNIT, check=check_scale)

    def __post_init__(self) -> None:
        self.descriptor, self.descriptor_params = _named_stage(
            self.descriptor, self.descriptor_params, DESCRIPTORS, Descriptor, "descriptor"
        )
        self.rejection, self.rejection_params = _named_stage(
            self.rejection, self.rejection_params, REJECTORS, Rejector, "rejection"
        )
        validate_settings(self, "")  # its own fields (the stage configs check themselves)
        # Fail early on unknown parameters and bad values (the typed objects check them).
        _ = self.descriptor_config, self.rejector_config

    @property
    def motion(self) -> MotionModel:
        """The motion model (`MotionModel`) of these settings: RANSAC's `dof` and `max_tilt`,
        which the final fit, the acceptance test and the verification assume too."""
        return self.ransac.motion

    @property
    def edge_radius(self) -> float:
        """Graph edge radius (m) that suits this config's scene scale (street: 20 m; "auto":
        the street's until the scale is estimated); used where the command line builds graphs
        from files without an explicit radius."""
        return scene_edge_radius(STREET_UNIT if self.scale == AUTO else self.scale)

    def resolved(self, unit: float, scene: dict[str, Any] | None = None) -> LocalizerConfig:
        """This config with the scene scale `unit` (metres) in place of "auto": each length
        that is at its street default becomes its street default times unit / 5 m, and the
        flat settings `scene` (a scene preset's, `sgloc.pipeline.presets.at_estimated_scale`) apply;
        the settings that differ from the defaults (given explicitly) stay. A config of a
        numeric scale is returned as it is."""
        if self.scale != AUTO:
            return self
        flat = {k: v for k, v in (scene or {}).items() if k != "scale"} | self.flat_settings()
        flat.pop("scale", None)
        accept = flat.pop("acceptance", None)
        if accept is not None:  # its settings one by one: a whole group would hide the scaled
            base = _flat_acceptance(dataclasses.asdict(AcceptanceConfig()))
            flat |= {f"acceptance_{k}": v for k, v in _flat_acceptance(accept).items()
                     if base.get(k) != v}  # fmt: skip
        return LocalizerConfig().with_overrides(**flat, scale=unit)

    @property
    def descriptor_config(self) -> Descriptor:
        """The descriptor these settings name, as its typed (dataclass) object."""
        try:
            return make_descriptor(self.descriptor, **self.descriptor_params)
        except TypeError as e:
            raise UnknownNameError(f"descriptor {self.descriptor!r}: {e}") from None

    @property
    def rejector_config(self) -> Rejector:
        """The rejector these settings name, as its typed (dataclass) object."""
        try:
            return make_rejector(self.rejection, **self.rejection_params)
        except TypeError as e:
            raise UnknownNameError(f"rejection {self.rejection!r}: {e}") from None

    def with_overrides(self, **overrides: Any) -> LocalizerConfig:
        """A copy with flat settings routed to their stage, e.g. `tau=3, min_similarity=0.6`.

        A bare name must belong to one stage only; `ransac_<field>`, `matching_<field>`,
        `acceptance_<field>`, `descriptor_<field>` and `rejection_<field>` name a stage's field
        explicitly. Names that would be read two ways
        (FLAT_AMBIGUOUS, e.g. `confidence`) and unknown names raise UnknownNameError. Every value
        is checked by the stage config it lands in (sgloc.validation).
        """
        overrides = dict(overrides)
        scaled: dict[str, Any] = {}
        if "scale" in overrides and overrides["scale"] != AUTO:
            scaled = self._scaled_lengths(overrides)
            explicit, overrides = overrides, scaled | overrides
        top = {k: overrides.pop(k) for k in ("descriptor", "rejection") if k in overrides}
        # A new descriptor or rejector starts from its own defaults (or the typed object's).
        params = {
            "descriptor_params": dict(self.descriptor_params),
            "rejection_params": dict(self.rejection_params),
        }
        for key, table, base in (
            ("descriptor", DESCRIPTORS, Descriptor),
            ("rejection", REJECTORS, Rejector),
        ):
            if key in top:
                top[key], params[f"{key}_params"] = _named_stage(top[key], {}, table, base, key)
        descriptor = top.get("descriptor", self.descriptor)
        rejection = top.get("rejection", self.rejection)
        stages: dict[str, dict[str, Any]] = {name: {} for name in _STAGES}
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
            out = dataclasses.replace(
                self,
                **top,
                **params,
                matching=dataclasses.replace(self.matching, **stages["matching"]),
                ransac=dataclasses.replace(self.ransac, **stages["ransac"]),
                acceptance=_replace_acceptance(acceptance or self.acceptance, stages),
            )
        except TypeError as e:  # a descriptor/rejector given a parameter it does not have
            raise UnknownNameError(f"unknown setting: {e}") from None
        if scaled:
            out._drop_default_lengths(explicit, scaled)
        return out

    def _scaled_lengths(self, overrides: dict[str, Any]) -> dict[str, Any]:
        """The flat length settings of the scene scale overrides["scale"] (`sgloc.maps.scale`): each
        length's street default times scale / 5 m, for the descriptor and rejector these
        overrides (or this config) name."""
        unit = overrides["scale"]
        if isinstance(unit, bool) or not isinstance(unit, (int, float)) or not unit > 0:
            raise InvalidSettingError(
                f"setting scale={unit!r}: give the scene's unit length in metres (a number > 0;"
                " street maps 5, forests 1.25, rooms 0.5: docs/scenes.md)."
            )
        f = scale_factor(unit)
        out = {"ransac_threshold": RansacConfig().threshold * f,
               "icp_max_distance": _DEFAULT_ICP_DISTANCE * f}  # fmt: skip
        accept = AcceptanceConfig().scaled(f)  # every length of AcceptanceConfig.LENGTHS
        for group_name, names in AcceptanceConfig.LENGTHS.items():
            stage = getattr(accept, group_name) if group_name else accept
            out |= {f"acceptance_{n}": getattr(stage, n) for n in names
                    if getattr(stage, n) is not None}  # fmt: skip
        for key, table in (("descriptor", DESCRIPTORS), ("rejection", REJECTORS)):
            name = overrides.get(key, getattr(self, key))
            klass = table.find(name) if isinstance(name, str) else type(name)
            ok = isinstance(klass, type) and dataclasses.is_dataclass(klass)
            lengths = _STAGE_LENGTHS & _fields(klass) if ok else set()
            default = klass() if lengths else None
            out |= {f"{key}_{n}": getattr(default, n) * f for n in sorted(lengths)}
        return out

    def _drop_default_lengths(self, overrides: dict[str, Any], scaled: dict[str, Any]) -> None:
        """Remove from the descriptor and rejector parameters the scaled lengths equal to their
        defaults (scale 5 m), so that `with_overrides(scale=5.0)` gives the default config."""
        for key in ("descriptor", "rejection"):
            params = getattr(self, f"{key}_params")
            klass = (DESCRIPTORS if key == "descriptor" else REJECTORS).find(getattr(self, key))
            for n in [n for n in list(params) if f"{key}_{n}" in scaled]:
                explicit = n in overrides or f"{key}_{n}" in overrides
                if not explicit and klass is not None and params[n] == getattr(klass(), n):
                    del params[n]

    def flat_settings(self) -> dict[str, Any]:
        """The settings in which this config differs from the defaults, as flat names: bare
        where a name means one setting (`tau`, `n_walks`), stage-qualified otherwise
        (`ransac_confidence`, `descriptor_radius`; always `ransac_threshold`):
        `LocalizerConfig().with_overrides(**cfg.flat_settings()) == cfg`."""
        base = LocalizerConfig()
        routes = _flat_routes(self.descriptor, self.rejection)

        def name(stage: str, field_name: str) -> str:
            bare = len(routes.get(field_name, [])) == 1 and field_name not in FLAT_AMBIGUOUS
            keep = bare and (stage, field_name) != ("ransac", "threshold")
            return field_name if keep else f"{_PREFIX[stage]}_{field_name}"

        out: dict[str, Any] = {}
        for key in ("descriptor", "rejection"):
            if getattr(self, key) != getattr(base, key):
                out[key] = getattr(self, key)
            params = getattr(self, f"{key}_params").items()
            out |= {name(f"{key}_params", k): v for k, v in params}
        for stage in ("matching", "ransac"):
            now, ref = (dataclasses.asdict(getattr(c, stage)) for c in (self, base))
            out |= {name(stage, k): v for k, v in now.items() if v != ref[k]}
        if self.acceptance != base.acceptance:
            out["acceptance"] = dataclasses.asdict(self.acceptance)
        for key in sorted(_TOP_LEVEL):
            if getattr(self, key) != getattr(base, key):
                out[key] = getattr(self, key)
        return out

    def to_dict(self) -> dict[str, Any]:
        """A nested dict of plain values: descriptor and rejection as registered names with
        their parameters, each stage config as a mapping of its fields."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> LocalizerConfig:
        """The config of a nested dict (as `to_dict` writes it); every value is checked."""
        if not isinstance(data, dict):
            raise SglocError(f"malformed localizer config: expected a mapping, got {data!r:.60}.")
        data = _int_keys(dict(data))  # class ids come back as strings from JSON
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
        """Write the config as YAML (`to_dict`)."""
        write_settings_data(path, self.to_dict(), "YAML")

    def to_json(self, path: str | Path) -> None:
        """Write the config as JSON (`to_dict`; class ids as strings)."""
        write_settings_data(path, self.to_dict(), "JSON")

    @classmethod
    def from_json(cls, path: str | Path) -> LocalizerConfig:
        """Read a config written by `to_json`."""
        return cls.from_dict(read_settings_data(path, "JSON"))

    def save(self, path: str | Path) -> None:
        """Write the config to `path`: JSON for a .json file, YAML otherwise."""
        write_settings_data(path, self.to_dict())

    @classmethod
    def load(cls, path: str | Path) -> LocalizerConfig:
        """Read a config written by `save` (JSON for a .json file, YAML otherwise;
        `sgloc.io.settings_file`, the one reader of settings files)."""
        return cls.from_dict(read_settings_data(path))

    @classmethod
    def from_yaml(cls, path: str | Path) -> LocalizerConfig:
        """Read a config written by `to_yaml`."""
        return cls.from_dict(read_settings_data(path, "YAML"))


def _named_stage(
    value: Any, params: Any, table: Registry[Any], base: type, kind: str
) -> tuple[Any, dict[str, Any]]:
    """(registered name, parameters) of a stage given by name, as a typed object, or as a
    mapping {"name": ..., field: value}; `params` add to (and override) the object's fields.
    An instance of an unregistered class is kept as it is (it runs, but is not serialisable)."""
    params = dict(params) if isinstance(params, dict) else params
    if isinstance(value, base):
        key = next((k for k, klass in table.items() if type(value) is klass), None)
        if key is None:
            return value, params
        default = type(value)()
        fields = {
            f.name: getattr(value, f.name)
            for f in dataclasses.fields(value)
            if getattr(value, f.name) != getattr(default, f.name)
        }
        return key, fields | (params or {})
    if isinstance(value, dict):
        fields = dict(value)
        if not isinstance(fields.get("name"), str):
            choices = ", ".join(table)
            raise SglocError(f"setting {kind}: a mapping needs a 'name' (one of {choices}).")
        name = fields.pop("name")
        return table.key(name), fields | (params or {})
    if isinstance(value, str):
        return table.key(value), params
    return value, params


def _flat_acceptance(nested: dict[str, Any]) -> dict[str, Any]:
    """The acceptance settings of `dataclasses.asdict(AcceptanceConfig)` by flat field name."""
    out = {k: v for k, v in nested.items() if k not in ("evidence", "verification")}
    for group_name in ("evidence", "verification"):
        out |= nested.get(group_name) or {}
    return out


def _int_keys(data: dict[str, Any]) -> dict[str, Any]:
    """class_weights read back from JSON: its class ids were written as strings."""
    weights = data.get("class_weights")
    if isinstance(weights, dict):
        try:
            data = {**data, "class_weights": {int(k): v for k, v in weights.items()}}
        except ValueError:
            raise SglocError("setting class_weights: class ids must be integers.") from None
    return data


def _acceptance(value: Any) -> AcceptanceConfig:
    """An AcceptanceConfig from itself, a bool (False switches the test off), or a mapping of
    its fields, flat or nested by group (`AcceptanceConfig.from_settings`)."""
    if isinstance(value, AcceptanceConfig):
        return value
    if isinstance(value, bool):
        return AcceptanceConfig(enabled=value)
    if value is not None and not isinstance(value, dict):
        raise SglocError(
            f"setting acceptance={value!r}: give True/False or a mapping of its fields."
        )
    try:
        return AcceptanceConfig.from_settings(value or {})
    except TypeError as e:
        raise UnknownNameError(f"setting acceptance: {e}") from None


def _replace_acceptance(base: AcceptanceConfig, stages: dict[str, dict[str, Any]]) -> Any:
    """`base` with the flat settings routed to the test and to its evidence and verification
    groups."""
    return dataclasses.replace(
        base,
        **stages["acceptance"],
        evidence=dataclasses.replace(base.evidence, **stages["evidence"]),
        verification=dataclasses.replace(base.verification, **stages["verification"]),
    )


#: Flat names that would be read two ways, with the spellings to use instead.
FLAT_AMBIGUOUS = {
    "confidence": "ransac_confidence (RANSAC's stop probability) or min_confidence (the "
    "acceptance test's strictness)",
    "radius": "acceptance_radius (the acceptance test's inlier radius) or descriptor_radius (the "
    "distance descriptors' radius); the graph edge radius is set when a graph is built or loaded",
    "enabled": "acceptance_enabled or acceptance=false (Python: acceptance=False)",
}
#: The stage configs whose fields are routed by flat name (evidence and verification: groups
#: of the acceptance stage).
_STAGES = ("matching", "ransac", "acceptance", "evidence", "verification")
_TOP_LEVEL = {"class_weights", "robust_refit", "class_scale", "icp", "icp_max_distance", "scale"}


def _flat_routes(descriptor: Any, rejection: Any) -> dict[str, list[tuple[str, str]]]:
    """{flat name: [(stage, field), ...]} of every bare and stage-qualified setting name."""
    desc = DESCRIPTORS.find(descriptor) if isinstance(descriptor, str) else None
    rej = REJECTORS.find(rejection) if isinstance(rejection, str) else None
    stages = {
        "matching": _fields(MatchingConfig),
        "ransac": _fields(RansacConfig),
        "acceptance": _fields(AcceptanceConfig) - {"evidence", "verification"},
        "evidence": _fields(EvidenceConfig),
        "verification": _fields(VerificationConfig),
        "descriptor_params": _fields(desc) if desc else set(),
        "rejection_params": _fields(rej) if rej else set(),
        "top": _TOP_LEVEL,
    }
    routes: dict[str, list[tuple[str, str]]] = {}
    for stage, names in stages.items():
        for name in names:
            routes.setdefault(name, []).append((stage, name))
            if stage != "top":
                routes.setdefault(f"{_PREFIX[stage]}_{name}", []).append((stage, name))
    return routes


#: The prefix of each stage's qualified setting names (`ransac_threshold`, `descriptor_radius`).
_PREFIX = {
    "matching": "matching",
    "ransac": "ransac",
    "acceptance": "acceptance",
    "evidence": "acceptance",  # the acceptance stage's groups keep its prefix
    "verification": "acceptance",
    "descriptor_params": "descriptor",
    "rejection_params": "rejection",
}


def _route(
    key: str, routes: dict[str, list[tuple[str, str]]], descriptor: Any, rejection: Any
) -> tuple[str, str]:
    if key in FLAT_AMBIGUOUS:
        raise UnknownNameError(f"setting {key!r} is ambiguous; use {FLAT_AMBIGUOUS[key]}.")
    found = routes.get(key, [])
    if len(found) == 1:
        return found[0]
    if found:
        options = ", ".join(f"{_PREFIX[s]}_{n}" if s in _PREFIX else n for s, n in found)
        raise UnknownNameError(f"setting {key!r} is ambiguous; use one of {options}.")
    import difflib

    close = difflib.get_close_matches(key, list(routes) + list(FLAT_AMBIGUOUS), n=1)
    hint = f"did you mean {' or '.join(map(repr, close))}? " if close else ""
    raise UnknownNameError(
        f"unknown setting {key!r} for descriptor {descriptor!r} and rejection {rejection!r}; "
        f"{hint}every setting and its default is in the config.yaml that "
        "`sgloc localize --example --out DIR` writes (docs/formats.md)."
    )


def _fields(klass: type | None) -> set[str]:
    return {f.name for f in dataclasses.fields(klass)} if klass is not None else set()
