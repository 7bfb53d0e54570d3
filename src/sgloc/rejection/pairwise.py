"""Moved to `sgloc.consistency` (shared with acceptance); kept so old imports work."""

from sgloc.consistency import (  # noqa: F401
    FORMS,
    TILE,
    consistency_bits,
    consistency_bool,
    consistency_matrix,
    consistent_blocks,
)
