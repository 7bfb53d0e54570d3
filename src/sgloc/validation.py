"""Checks of user-given values: settings (type, range, finiteness) and graph arrays (shape,
finiteness, documented size limits). Each failure is an SglocError naming the value and what is
allowed. This module imports nothing of the pipeline, so every stage may use it."""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np

from sgloc.errors import InvalidGraphError, SglocError

#: Most objects in one graph (a city's object map). Memory is linear in the objects: the
#: descriptors are n x L x bins floats per graph (distance_histogram: 16 bins, 1 KB per object
#: for 8 classes), candidate matching works class by class in blocks, and above
#: `sgloc.consistency.pairwise.ALL_PAIRS_LIMIT` candidates rejection checks pairs only within a
# radius
#: and acceptance samples pairs; no n x n array is built on the default path. Time is
#: dominated by the descriptor comparison, which compares every query object with every
#: target object of its class.
MAX_VERTICES = 1_000_000
#: Most distinct classes in one graph (class ids themselves may be any integer in [0, MAX_LABEL]:
#: the localizer renumbers the classes present to 0..L-1 before sizing anything by them).
MAX_CLASSES = 64
#: Largest class id.
MAX_LABEL = 2**31 - 1
#: Largest coordinate magnitude, metres: a map 10,000 km across. Beyond it float64 distances
#: lose the millimetres the pipeline needs, and it is always a unit or file error.
MAX_COORDINATE = 1e7


class InvalidSettingError(SglocError):
    """A setting has the wrong type or a value outside its allowed range."""


def _is_number(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def check_real(
    name: str,
    value: Any,
    low: float | None = None,
    high: float | None = None,
    *,
    low_open: bool = False,
    high_open: bool = False,
    none_ok: bool = False,
    unit: str = "",
) -> float | None:
    """`value` as a finite float within [low, high] (ends open when asked); else an
    InvalidSettingError naming `name` and the allowed range."""
    if value is None and none_ok:
        return None
    lo = "-inf" if low is None else f"{low:g}"
    hi = "inf" if high is None else f"{high:g}"
    allowed = f"{'(' if low_open else '['}{lo}, {hi}{')' if high_open else ']'}"
    allowed = f"a finite number in {allowed}{' ' + unit if unit else ''}"
    allowed += " or None" if none_ok else ""
    if not _is_number(value) or not math.isfinite(float(value)):
        raise InvalidSettingError(f"setting {name}={value!r}: must be {allowed}.")
    v = float(value)
    if low is not None and (v < low or (low_open and v == low)):
        raise InvalidSettingError(f"setting {name}={value!r}: must be {allowed}.")
    if high is not None and (v > high or (high_open and v == high)):
        raise InvalidSettingError(f"setting {name}={value!r}: must be {allowed}.")
    return v


def check_int(
    name: str, value: Any, low: int | None = None, high: int | None = None, *, none_ok=False
) -> int | None:
    """`value` as an int within [low, high]; bools and non-integral numbers are refused."""
    if value is None and none_ok:
        return None
    lo = "-inf" if low is None else str(low)
    hi = "inf" if high is None else str(high)
    allowed = f"an integer in [{lo}, {hi}]" + (" or None" if none_ok else "")
    integral = isinstance(value, numbers.Integral) and not isinstance(value, bool)
    if not integral or (low is not None and value < low) or (high is not None and value > high):
        raise InvalidSettingError(f"setting {name}={value!r}: must be {allowed}.")
    return int(value)


def check_bool(name: str, value: Any) -> bool:
    """`value` if it is a bool (numpy bools too); 0/1 or strings are refused."""
    if not isinstance(value, bool | np.bool_):
        raise InvalidSettingError(f"setting {name}={value!r}: must be True or False.")
    return bool(value)


#: Values of LocalizerConfig.class_scale; False and True stand for "none" and "full".
CLASS_SCALE_CHOICES = ("none", "height", "full")


def check_class_scale(name: str, value: Any) -> str:
    """One of CLASS_SCALE_CHOICES; a bool maps to "full" (True) or "none" (False)."""
    if isinstance(value, bool | np.bool_):
        return "full" if value else "none"
    return check_choice(name, value, CLASS_SCALE_CHOICES, "per-class residual scales")


def check_choice(name: str, value: Any, choices: Iterable[str], what: str = "") -> str:
    """`value` if it is one of `choices` (strings); `what` describes the setting in errors."""
    options = sorted(choices)
    if not isinstance(value, str) or value not in options:
        what = f" ({what})" if what else ""
        raise InvalidSettingError(f"setting {name}={value!r}{what}: must be one of {options}.")
    return value


def check_class_weights(name: str, value: Any) -> dict[int, float] | None:
    """{class id (int >= 0): weight (finite, > 0)} or None."""
    if value is None:
        return None
    if not isinstance(value, Mapping):
        raise InvalidSettingError(
            f"setting {name}={value!r}: must be a mapping {{class id: weight}} or None."
        )
    out = {}
    for c, w in value.items():
        cid = int(c) if isinstance(c, str) and c.strip().isdigit() else c
        check_int(f"{name} class id", cid, 0, MAX_LABEL)
        out[int(cid)] = check_real(f"{name}[{cid}]", w, 0.0, low_open=True)
    return out


def check_graph_arrays(
    name: str, positions: np.ndarray, labels: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """positions (n,3) finite float64 within +-MAX_COORDINATE and labels (n,) int64 class ids in
    [0, MAX_LABEL], n <= MAX_VERTICES, at most MAX_CLASSES distinct; InvalidGraphError else."""
    pos = np.asarray(positions)
    lab = np.asarray(labels)
    if pos.ndim == 1 and pos.size == 0:
        pos = pos.reshape(0, 3)
    if pos.dtype.kind not in "fiu" or pos.ndim != 2 or pos.shape[1] != 3:
        raise InvalidGraphError(
            f"{name}: positions must be numbers of shape (n, 3), got {pos.dtype} {pos.shape}; "
            "pass one x, y, z row per object."
        )
    if lab.ndim != 1 or lab.shape[0] != pos.shape[0]:
        raise InvalidGraphError(
            f"{name}: labels must have shape ({pos.shape[0]},) to match the positions, "
            f"got {lab.shape}."
        )
    if len(pos) > MAX_VERTICES:
        raise InvalidGraphError(
            f"{name}: {len(pos)} objects, more than the limit of {MAX_VERTICES:,}; split the "
            "map into submaps or merge nearby objects."
        )
    pos = pos.astype(np.float64)
    # One pass when all is well: the largest |coordinate| is within range (NaN compares False).
    if pos.size and not np.abs(pos).max() <= MAX_COORDINATE:
        _refuse_positions(name, pos)
    return pos, _check_labels(name, lab)


def _refuse_positions(name: str, pos: np.ndarray) -> None:
    """The InvalidGraphError of positions (n,3) holding NaN, infinite or too large values."""
    finite = np.isfinite(pos).all(axis=1)
    if not finite.all():
        bad = np.flatnonzero(~finite)
        raise InvalidGraphError(
            f"{name}: {bad.size} position(s) are NaN or infinite (first at row {bad[0]}); "
            "drop those objects before building the graph."
        )
    row = int(np.argmax(np.abs(pos).max(axis=1)))
    raise InvalidGraphError(
        f"{name}: position {pos[row].tolist()} at row {row} is beyond +-{MAX_COORDINATE:g} "
        "m; positions must be metres in a local map frame."
    )


def _check_labels(name: str, lab: np.ndarray) -> np.ndarray:
    if lab.size and lab.dtype.kind not in "iu":
        if lab.dtype.kind != "f" or not np.all(np.isfinite(lab)) or np.any(lab != np.round(lab)):
            raise InvalidGraphError(f"{name}: labels must be integer class ids, got {lab.dtype}.")
    if lab.size and (lab.min() < 0 or lab.max() > MAX_LABEL):
        raise InvalidGraphError(
            f"{name}: labels must be class ids >= 0 and <= {MAX_LABEL} (found {lab.min()} .. "
            f"{lab.max()}); unknown classes must be removed or mapped to an id."
        )
    lab = lab.astype(np.int64)
    # Ids below MAX_CLASSES cannot name more classes than that: no count needed.
    n_classes = len(np.unique(lab)) if lab.size and lab.max() >= MAX_CLASSES else 0
    if n_classes > MAX_CLASSES:
        raise InvalidGraphError(
            f"{name}: {n_classes} distinct classes, more than the limit of {MAX_CLASSES}; "
            "is the label field really a class (not a colour or an instance id)?"
        )
    return lab


# -- settings of the stage configs ------------------------------------------------------------
#: A setting's check: (name, value) -> the value (normalised, e.g. 5 -> 5.0 for metres), or an
#: InvalidSettingError naming `name` and what is allowed.
Check = Callable[[str, Any], Any]

#: Largest number of RANSAC hypotheses, random walks per vertex, etc.: bounds run time.
MAX_ITERATIONS = 10_000_000
#: Longest random walk: the descriptor has L**walk_length bins (int64 codes; L <= 2 MAX_CLASSES).
MAX_WALK_LENGTH = 8


def setting(default: Any = dataclasses.MISSING, *, check: Check, **field_options: Any) -> Any:
    """A stage config's dataclass field with its allowed values declared beside it:
    `tau: float = setting(5.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))`.
    `validate_settings` applies `check` to the field's value (`field_options`: those of
    `dataclasses.field`, e.g. default_factory)."""
    return dataclasses.field(default=default, metadata={"check": check}, **field_options)


def same_setting(config: type, name: str) -> Any:
    """A field declaring what the dataclass `config` declares for its setting `name` (default
    or default factory, and check): a setting two configs share is declared once, in one of
    them, and the other takes it by name (`sgloc.extraction.ExtractionConfig`'s association
    settings are `sgloc.maps.association.AssociationSettings`')."""
    f = next((f for f in dataclasses.fields(config) if f.name == name), None)
    if f is None:
        raise TypeError(f"{config.__name__} declares no setting {name!r}.")
    return dataclasses.field(default=f.default, default_factory=f.default_factory,
                             metadata=f.metadata)


def check_of(f: dataclasses.Field) -> Check | None:
    """The check a field declares (None: it declares none)."""
    return f.metadata.get("check")


def real(low=None, high=None, *, low_open=False, high_open=False, none_ok=False, unit="") -> Check:
    """A finite number in [low, high] (ends open when asked); see `check_real`."""

    def check(name: str, value: Any) -> float | None:
        return check_real(
            name,
            value,
            low,
            high,
            low_open=low_open,
            high_open=high_open,
            none_ok=none_ok,
            unit=unit,
        )

    return check


def integer(low: int | None = None, high: int | None = None, *, none_ok: bool = False) -> Check:
    """An int in [low, high]; see `check_int`."""
    return lambda name, value: check_int(name, value, low, high, none_ok=none_ok)


def int_choice(*choices: int) -> Check:
    """One of the ints `choices`."""

    def check(name: str, value: Any) -> int:
        if isinstance(value, bool) or value not in choices:
            raise InvalidSettingError(f"setting {name}={value!r}: must be one of {list(choices)}.")
        return int(value)

    return check


def choice(*choices: str, what: str = "") -> Check:
    """One of the strings `choices`; `what` describes the setting in errors."""
    return lambda name, value: check_choice(name, value, choices, what)


def flag() -> Check:
    """True or False; see `check_bool`."""
    return check_bool


def span(low: float, high: float, *, whole: bool = False, unit: str = "") -> Check:
    """A range `(a, b)` with low <= a <= b <= high, as a tuple of floats (of ints: `whole`)."""
    inner = integer(int(low), int(high)) if whole else real(low, high, unit=unit)

    def check(name: str, value: Any) -> tuple:
        try:
            a, b = value
        except (TypeError, ValueError):
            raise InvalidSettingError(
                f"setting {name}={value!r}: must be a range (low, high)."
            ) from None
        a, b = inner(f"{name}[0]", a), inner(f"{name}[1]", b)
        if a > b:
            raise InvalidSettingError(f"setting {name}={value!r}: low must not exceed high.")
        return (a, b)

    return check


def class_ids(name: str, value: Any) -> tuple[int, ...]:
    """A sequence of class ids (whole numbers), as a tuple of ints."""
    try:
        items = tuple(value)
    except TypeError:
        raise InvalidSettingError(
            f"setting {name}={value!r}: must be a list of class ids (whole numbers)."
        ) from None
    bad = [c for c in items if isinstance(c, bool) or not _is_number(c) or float(c) != int(c)]
    if bad:
        raise InvalidSettingError(
            f"setting {name}={value!r}: {bad[0]!r} is not a class id (a whole number)."
        )
    return tuple(int(c) for c in items)


def group(klass: type) -> Check:
    """An instance of the settings group `klass` (which checks its own fields)."""

    def check(name: str, value: Any) -> Any:
        if not isinstance(value, klass):
            raise InvalidSettingError(
                f"setting {name}={value!r:.60}: must be a {klass.__name__}."
            )
        return value

    return check


def validate_settings(config: Any, prefix: str | None = None) -> None:
    """Check (and normalise: 5 -> 5.0 for metres) every field of a stage config dataclass by
    the check it declares (`setting`); InvalidSettingError naming `prefix.field` (default
    prefix: the stage's registered `name`) and what is allowed. A field that declares no
    check is only checked to be finite when it is a number (tests/test_validation.py makes
    sure every registered stage's fields declare one)."""
    if prefix is None:
        prefix = getattr(config, "name", None) or type(config).__name__
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        name = f"{prefix}.{f.name}" if prefix else f.name
        check = check_of(f)
        if check is not None:
            object.__setattr__(config, f.name, check(name, value))
        elif _is_number(value) and not math.isfinite(float(value)):
            raise InvalidSettingError(f"setting {name}={value!r}: must be a finite number.")


def stage_name(name: str, value: Any) -> Any:
    """A stage (descriptor, rejector) given by registered name or as a callable object."""
    if not isinstance(value, str) and not callable(value):
        raise InvalidSettingError(f"setting {name}={value!r}: must be a registered name.")
    return value


def parameters(name: str, value: Any) -> Any:
    """A mapping of a stage's parameters."""
    if not isinstance(value, Mapping):
        raise InvalidSettingError(f"setting {name}: must be a mapping of parameters.")
    return value


def check_seed(seed: Any, name: str = "seed") -> Any:
    """`seed` as given when it is a Generator, None (fresh entropy) or a non-negative integer
    (returned as int); anything else (negative, fractional, bool, text) is refused."""
    if seed is None or isinstance(seed, np.random.Generator):
        return seed
    if not isinstance(seed, numbers.Integral) or isinstance(seed, bool | np.bool_) or seed < 0:
        raise InvalidSettingError(
            f"{name}={seed!r}: must be a non-negative integer (or None for a fresh random seed)."
        )
    return int(seed)


def random_generator(seed: Any, name: str = "seed") -> np.random.Generator:
    """A numpy Generator from `seed` (`check_seed`; a Generator is used as is)."""
    return np.random.default_rng(check_seed(seed, name))
