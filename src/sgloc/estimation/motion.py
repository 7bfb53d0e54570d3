"""MotionModel: which rigid motions an alignment may be (degrees of freedom, gravity tilt)."""

from __future__ import annotations

from dataclasses import dataclass

from sgloc.validation import InvalidSettingError, check_real


@dataclass(frozen=True)
class MotionModel:
    """The motion between two maps that RANSAC, the final fit, the acceptance test, the
    whole-map verification and `register` assume.

    dof: 6 (any rigid motion; hypotheses from 3 matches) or 4 (ground vehicles: x, y, z and
        yaw, roll and pitch fixed by gravity; hypotheses from 2 matches, about the z axis).
    max_tilt: degrees; when set, the maps share gravity (z up) up to this tilt: hypotheses and
        fits that tilt the up axis more (upside-down or mirrored alignments) are refused. With
        dof=4 the fits may tilt up to this much (None or 0: yaw only). None: no assumption.

    `LocalizerConfig` and `RansacConfig` hold it as their flat settings `dof` and `max_tilt`
    (`RansacConfig.motion` is this object); `localize(q, t, dof=6, max_tilt=None)` sets both.
    """

    dof: int = 4
    max_tilt: float | None = 15.0

    def __post_init__(self) -> None:
        if isinstance(self.dof, bool) or self.dof not in (4, 6):
            raise InvalidSettingError(
                f"setting dof={self.dof!r}: must be one of [4, 6] (4: x, y, z, yaw; 6: any "
                "rigid motion)."
            )
        tilt = check_real("max_tilt", self.max_tilt, 0.0, 180.0, low_open=True, none_ok=True,
                          unit="degrees")  # fmt: skip
        object.__setattr__(self, "dof", int(self.dof))
        object.__setattr__(self, "max_tilt", tilt)

    @property
    def sample_size(self) -> int:
        """Matches a minimal sample needs to fix a hypothesis (2 with dof=4, else 3)."""
        return 2 if self.dof == 4 else 3


#: The ground vehicle's model (the default of `localize`).
GROUND_VEHICLE = MotionModel()
#: Any rigid motion, no gravity assumption (the default of `register`).
ANY_RIGID = MotionModel(dof=6, max_tilt=None)
