"""Settings of the acceptance stage, one dataclass per job.

`AcceptanceConfig` is the test itself and holds the other two: `EvidenceConfig` (which
candidates count as evidence: the ratio test by query size, also flagged during matching) and
`VerificationConfig` (the whole-map verification of small queries). Every field keeps its flat
name (`localize(q, t, distinct_ratio=..., verify_small=...)`, `acceptance_<field>`), and a
mapping of the three may be flat (`{"min_confidence": 0.9, "distinct_ratio": None}`) or
nested (`{"evidence": {"distinct_ratio": None}}`): `AcceptanceConfig.from_settings`.

Words: a *distinctive* match is clearly better than its rival (the ratio test; its setting
keeps the name `distinct_ratio`); two *distinct* alignments differ by more than
`distinct_translation` or `distinct_rotation` (`rivals.distinct_from`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from sgloc.validation import (
    MAX_COORDINATE,
    MAX_ITERATIONS,
    MAX_VERTICES,
    InvalidSettingError,
    flag,
    group,
    integer,
    real,
    setting,
    validate_settings,
)


@dataclass
class EvidenceConfig:
    """Which descriptor candidates the acceptance test weighs.

    distinct_ratio: the test weighs only the distinctive candidates, those whose best match passes
        the ratio test (1 - s_1) / (1 - s_2) <= distinct_ratio (`MatchingConfig.max_ratio`): in a
        repetitive place near-tied matches support a wrong alignment as readily as the right
        one. None: every candidate.
    small_query, small_distinct_ratio: a query graph with fewer than `small_query` objects (one
        scan, a short stretch) is tested with the looser ratio `small_distinct_ratio` (None:
        every candidate counts): its objects see only part of their neighbourhood, so fewer
        of its right matches are distinctive (`ratio_for`). 0: no query is small. Such a query
        is also the one the whole-map verification may check (`VerificationConfig`). Measured
        on the hard-case benchmark's tuning pairs and on small crops of non-overlapping maps
        (docs/acceptance.md): 0.9 or no filter gave false accepts in repetitive places.
    small_exclusion: metres; for a small query, the ratio test's rival is the best same-class
        target farther than this from the candidate's target (`spatially_distinctive`): a near tie
        with a neighbour in the same place is no ambiguity about the place. 0: the second
        best of the class. (Measured: for large queries too it let 2 of 480 non-overlapping
        pairs of the rendered city through.)
    """

    distinct_ratio: float | None = setting(0.8, check=real(0.0, 1.0, low_open=True, none_ok=True))
    small_query: int = setting(30, check=integer(0, MAX_VERTICES))
    small_distinct_ratio: float | None = setting(
        0.85, check=real(0.0, 1.0, low_open=True, none_ok=True)
    )
    small_exclusion: float = setting(10.0, check=real(0.0, MAX_COORDINATE, unit="m"))

    def __post_init__(self) -> None:
        validate_settings(self, "acceptance")  # the checks declared beside the fields

    def is_small(self, n_query: int) -> bool:
        """Whether a query graph of `n_query` objects is small (fewer than `small_query`)."""
        return n_query < self.small_query

    def ratio_for(self, n_query: int) -> float | None:
        """The distinctiveness ratio for a query graph of `n_query` objects (None: every
        candidate is evidence): `small_distinct_ratio` below `small_query` objects, else
        `distinct_ratio`."""
        if self.is_small(n_query) and self.distinct_ratio is not None:
            return self.small_distinct_ratio
        return self.distinct_ratio

    def exclusion_for(self, n_query: int) -> float:
        """Metres around a candidate's target where no rival is sought, for a query graph of
        `n_query` objects: `small_exclusion` below `small_query` objects, else 0."""
        return float(self.small_exclusion) if self.is_small(n_query) else 0.0


@dataclass
class VerificationConfig:
    """The whole-map verification of small queries (`verify_small_query`).

    verify_small: with the 4-dof model, a small query (`EvidenceConfig.small_query`) the test
        refuses is verified against the whole target map: pair hypotheses from each query
        object's `verify_top_k` candidates (at most `verify_hypotheses` scored), scored by how
        many query objects land within `verify_radius` metres of a same-class target object;
        chance from the density of same-class targets within `verify_density_radius` metres.
        Chosen on the hard-case benchmark's tuning pairs and 300 extra one-scan negatives
        (docs/acceptance.md).
    """

    verify_small: bool = setting(True, check=flag())
    verify_top_k: int = setting(5, check=integer(1, 1000))
    verify_radius: float = setting(1.5, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    verify_density_radius: float = setting(
        15.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m")
    )
    verify_hypotheses: int = setting(4096, check=integer(1, MAX_ITERATIONS))

    def __post_init__(self) -> None:
        validate_settings(self, "acceptance")  # the checks declared beside the fields


#: The groups an AcceptanceConfig holds, by field name.
_GROUPS = {"evidence": EvidenceConfig, "verification": VerificationConfig}


@dataclass
class AcceptanceConfig:
    """Settings of the acceptance test (`sgloc.acceptance.assessment` describes the model).

    enabled: run the test (False: Guo's rule alone decides; confidence is left None).
    min_confidence: accept when confidence >= this (the strictness; in [0, 1]).
    radius: inlier radius in metres for the test; None uses the RANSAC threshold.
    min_spread: metres; inliers whose standard deviation along their second principal axis is
        below this are (nearly) collinear and give confidence 0 (with dof=4, where gravity
        fixes the rotation about such a line: along the first principal axis of their xy,
        at least DOF4_SPREAD_FACTOR = 2 x min_spread).
    distinct_translation, distinct_rotation: metres / degrees; an alternative hypothesis is
        distinct when its transform differs from the best by more than either.
    runner_up_samples: hypotheses drawn when searching for the best distinct alternative.
    repetition_shifts: how many self-similar shifts of the target near the estimate (found
        from its same-class object offsets) the query is also scored under
        (`sgloc.acceptance.repetition`); 0 (the default): none. A shift that lands the query's
        objects about as well as the estimate makes the result ambiguous. 8 refuses a crop of
        a lattice at a one-period offset; it costs about 1-1.5 ms per accepted alignment on
        Guo's Airsim maps and refused one held-out one-scan KITTI query that the default
        localizes (docs/acceptance.md), hence off by default.
    repetition_search: metres; the longest shift looked for (the longest period of a repeating
        layout; the shortest is `distinct_translation`).
    other_places: how many other places of the target, where it repeats itself near an
        accepted alignment (within `distinct_translation`..`repetition_search` metres), the
        query is refitted at and compared with the alignment, object by object
        (`sgloc.acceptance.places`); 0 (the default): none. A place where the refitted query
        lands about as many objects makes the result ambiguous (identical offices of a floor).
    layout_shifts: how many self-similar shifts of each map (found as for
        `repetition_shifts`, up to `repetition_search` metres) measure how much of the maps'
        layout repeats; an estimate that lands no more of the query than a copy of that
        repeating layout would (counted against the test's hypotheses) is refused as
        ambiguous (`sgloc.acceptance.repetition`, check 3). 0 (the default): no such check.
        8 removes most lattice-offset accepts of a street grid, but with few shifted objects
        the estimate is coarse: on KITTI 00 and on small overlaps of the rendered city it
        refused right accepts the default keeps (docs/acceptance.md, docs/repetition.md).
    min_agreement: fraction in [0, 1]; of the query objects the estimate puts next to a target
        object (within `cover_radius`), at least this fraction must land on an object of their
        class (within `agreement_radius`) when there are at least `min_covered` of them; 0: no
        such check. Chosen on pair attempts of the rendered 12x12-block city, seeds 0-1
        (docs/acceptance.md).
    agreement_radius, cover_radius: metres; None: agreement_radius is a quarter of the test's
        radius, or twice the median residual of the inliers when that is larger (noisy maps),
        and cover_radius twice agreement_radius (`repetition_radii`): they follow the scene's
        scale with the RANSAC threshold.
    evidence: which candidates count (`EvidenceConfig`).
    verification: the whole-map verification of small queries (`VerificationConfig`).
    """

    enabled: bool = setting(True, check=flag())
    min_confidence: float = setting(0.9999, check=real(0.0, 1.0))
    radius: float | None = setting(
        None, check=real(0.0, MAX_COORDINATE, low_open=True, none_ok=True, unit="m")
    )
    min_spread: float = setting(5.0, check=real(0.0, MAX_COORDINATE, unit="m"))
    distinct_translation: float = setting(10.0, check=real(0.0, MAX_COORDINATE, unit="m"))
    distinct_rotation: float = setting(10.0, check=real(0.0, 180.0, unit="degrees"))
    runner_up_samples: int = setting(128, check=integer(0, MAX_ITERATIONS))
    repetition_shifts: int = setting(0, check=integer(0, 1000))
    repetition_search: float = setting(
        100.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m")
    )
    other_places: int = setting(0, check=integer(0, 1000))
    layout_shifts: int = setting(0, check=integer(0, 1000))
    min_agreement: float = setting(0.0, check=real(0.0, 1.0))
    min_covered: int = setting(10, check=integer(1, MAX_VERTICES))
    agreement_radius: float | None = setting(
        None, check=real(0.0, MAX_COORDINATE, low_open=True, none_ok=True, unit="m")
    )
    cover_radius: float | None = setting(
        None, check=real(0.0, MAX_COORDINATE, low_open=True, none_ok=True, unit="m")
    )
    evidence: EvidenceConfig = setting(default_factory=EvidenceConfig, check=group(EvidenceConfig))
    verification: VerificationConfig = setting(
        default_factory=VerificationConfig, check=group(VerificationConfig)
    )

    def __post_init__(self) -> None:
        validate_settings(self, "acceptance")  # the checks declared beside the fields

    #: The settings in metres, by group ("": the test's own): what a scene's scale scales
    #: (`scaled`). Every length the acceptance stage uses is one of these, a multiple of one,
    #: or the RANSAC threshold (`radius` None).
    LENGTHS: ClassVar[dict[str, tuple[str, ...]]] = {
        "": ("radius", "min_spread", "distinct_translation", "repetition_search",
             "agreement_radius", "cover_radius"),
        "evidence": ("small_exclusion",),
        "verification": ("verify_radius", "verify_density_radius"),
    }  # fmt: skip

    def scaled(self, factor: float) -> AcceptanceConfig:
        """A copy with every length setting (`LENGTHS`; None stays None) multiplied by
        `factor` > 0: the same test for a scene `factor` times the size (a room: well
        below 1)."""
        if not (np.isfinite(factor) and factor > 0):
            raise InvalidSettingError(f"scale factor {factor!r}: must be a positive number.")

        def times(obj: Any, names: tuple[str, ...]) -> Any:
            new = {n: None if getattr(obj, n) is None else getattr(obj, n) * factor
                   for n in names}  # fmt: skip
            return dataclasses.replace(obj, **new)

        groups = {g: times(getattr(self, g), names) for g, names in self.LENGTHS.items() if g}
        return dataclasses.replace(times(self, self.LENGTHS[""]), **groups)

    def repetition_radii(self, radius: float, precision: float = 0.0) -> tuple[float, float]:
        """(agreement_radius, cover_radius) in metres for the test's radius `radius` and the
        median inlier residual `precision` (metres): the settings, or max(radius / 4,
        2 x precision) and twice that."""
        land = self.agreement_radius
        if land is None:
            land = max(radius / 4.0, 2.0 * precision)
        cover = self.cover_radius if self.cover_radius is not None else 2.0 * land
        return float(land), float(max(cover, land))

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any]) -> AcceptanceConfig:
        """The config of a flat or nested mapping of its fields (see the module docstring);
        TypeError for an unknown name."""
        own: dict[str, Any] = {}
        groups: dict[str, dict[str, Any]] = {name: {} for name in _GROUPS}
        owner = {f.name: g for g, klass in _GROUPS.items() for f in dataclasses.fields(klass)}
        for key, value in settings.items():
            if key in _GROUPS:
                groups[key] |= _as_mapping(value, key)
            elif key in owner:
                groups[owner[key]][key] = value
            else:
                own[key] = value
        made = {name: klass(**groups[name]) for name, klass in _GROUPS.items()}
        return cls(**own, **made)


def _as_mapping(value: Any, name: str) -> dict[str, Any]:
    """A group given as its dataclass or as a mapping of its fields."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return dataclasses.asdict(value)
    if isinstance(value, Mapping):
        return dict(value)
    raise InvalidSettingError(
        f"setting acceptance.{name}={value!r:.60}: give a mapping of its fields."
    )
