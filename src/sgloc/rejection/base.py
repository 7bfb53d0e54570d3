"""What every outlier rejector is: correspondences in, indices of the kept ones out."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sgloc.validation import validate_settings


@dataclass
class Rejector:
    """Base class. Subclasses are dataclasses of their parameters.

    `__call__(src, dst, scores)` takes the matched points, src (m,3) in the query frame and
    dst (m,3) in the target frame (row i of each is match i), and the descriptor similarity
    of each match (m,) or None, and returns the sorted int indices of the matches it keeps.
    """

    name = "base"

    def __post_init__(self) -> None:
        validate_settings(self)  # type, range, finiteness of every field (sgloc.validation)

    def __call__(
        self, src: np.ndarray, dst: np.ndarray, scores: np.ndarray | None = None
    ) -> np.ndarray:
        raise NotImplementedError


@dataclass
class NoRejection(Rejector):
    """Keep every match: the baseline the paper compares against (RANSAC alone)."""

    name = "none"

    def __call__(self, src, dst, scores=None):
        return np.arange(len(src))
