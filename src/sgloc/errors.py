"""Exceptions a user can cause. Each message names the input and the fix."""

from __future__ import annotations


class SglocError(ValueError):
    """Base class of every error caused by user input; the CLI prints it in one line, exit 2."""


class GraphFileError(SglocError):
    """A graph file is missing, unreadable or malformed."""


class InvalidGraphError(SglocError):
    """Positions or labels are malformed: wrong shape, NaN, negative class, empty graph."""


class UnknownNameError(SglocError):
    """An unknown descriptor, rejector, dataset or experiment name."""


class DegenerateGeometryError(SglocError):
    """Too few or (nearly) collinear points to fix a rigid transform."""


class DatasetError(SglocError):
    """A dataset folder or file is missing or malformed."""


class TooManyMatchesError(SglocError):
    """More matches than the pairwise consistency pass can hold in memory."""


class OutputPathError(SglocError):
    """An output path sgloc may not write: it holds the working folder, an input or files sgloc
    did not write, or another run is writing it."""
