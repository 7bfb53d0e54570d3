"""sgloc's own compact, versioned live messages (docs/formats.md, "Live messages"): a robot's
keyframe, its end, a hello; the server's correction and events. Every message is an 8-byte
header (magic b"SGLC", version, kind, two reserved zero bytes) and a little-endian body.
`decode` checks every byte count and value and raises `MessageError` (one line) on anything
else, so a server counts and drops a malformed payload."""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass

import numpy as np

from sgloc.errors import SglocError

MAGIC = b"SGLC"
VERSION = 1
KEYFRAME, CORRECTION, EVENT, END, HELLO = 1, 2, 3, 4, 5
#: Most objects one keyframe may carry.
MAX_OBJECTS = 1 << 20
#: Largest event body (bytes).
MAX_EVENT_BYTES = 1 << 16

_HEADER = struct.Struct("<4sBBH")
_KEYFRAME = struct.Struct("<Qq16dI")  # seq, stamp_ns, T (row-major), n objects
_CORRECTION = struct.Struct("<QqQB7x16d")  # seq, held stamp_ns, revision, flags, T
PLACED, FINISHED = 1, 2  # the correction's flags
_END = struct.Struct("<Qq")  # seq, stamp_ns of the robot's last keyframe


class MessageError(SglocError):
    """A payload that is not a valid sgloc live message."""


@dataclass(frozen=True)
class Keyframe:
    """One keyframe: seq (the robot's counter, increasing), stamp_ns, T_odom_sensor (4,4),
    positions (n,3) metres in the sensor frame, labels (n,) class ids."""

    seq: int
    stamp_ns: int
    T_odom_sensor: np.ndarray
    positions: np.ndarray
    labels: np.ndarray


@dataclass(frozen=True)
class Correction:
    """The server's answer to a robot: seq of the robot's last message it took (0: none),
    held_ns the stamp of the robot's last keyframe it holds (-1: none), the fleet revision,
    placed, T_fleet_odom (4,4; map -> odom; identity while not placed), finished: the server
    took the robot's `End` after its last keyframe."""

    seq: int
    held_ns: int
    revision: int
    placed: bool
    T_fleet_odom: np.ndarray
    finished: bool = False


@dataclass(frozen=True)
class End:
    """The robot sent its last keyframe (stamp_ns); more may still follow."""

    seq: int
    stamp_ns: int


@dataclass(frozen=True)
class Hello:
    """A robot asks for its correction (on connecting or reconnecting)."""


@dataclass(frozen=True)
class EventMessage:
    """One of the session's events as `sgloc.online.Event.to_dict` gives it."""

    event: dict


def _header(kind: int) -> bytes:
    return _HEADER.pack(MAGIC, VERSION, kind, 0)


def encode_keyframe(seq: int, stamp_ns: int, T_odom_sensor, positions, labels) -> bytes:
    """A keyframe message (see `Keyframe`)."""
    T = np.asarray(T_odom_sensor, "<f8").reshape(16)
    pos = np.ascontiguousarray(positions, "<f8").reshape(-1, 3)
    lab = np.asarray(labels).reshape(-1)
    if lab.size and (lab.min() < 0 or lab.max() > np.iinfo(np.int32).max):
        raise MessageError("keyframe labels must be class ids in 0 .. 2**31 - 1.")
    lab = np.ascontiguousarray(lab, "<i4")
    if len(lab) != len(pos):
        raise MessageError(f"a keyframe needs one label per object: {len(pos)} objects, "
                           f"{len(lab)} labels.")
    return (_header(KEYFRAME) + _KEYFRAME.pack(int(seq), int(stamp_ns), *T.tolist(), len(pos))
            + pos.tobytes() + lab.tobytes())


def encode_correction(seq: int, held_ns: int, revision: int, T_fleet_odom=None,
                      finished: bool = False) -> bytes:
    """A correction message (see `Correction`); T_fleet_odom None: not placed."""
    T = np.eye(4) if T_fleet_odom is None else np.asarray(T_fleet_odom, np.float64)
    flags = (PLACED if T_fleet_odom is not None else 0) | (FINISHED if finished else 0)
    return _header(CORRECTION) + _CORRECTION.pack(int(seq), int(held_ns), int(revision), flags,
                                                  *T.ravel().tolist())


def encode_end(seq: int, stamp_ns: int) -> bytes:
    return _header(END) + _END.pack(int(seq), int(stamp_ns))


def encode_hello() -> bytes:
    return _header(HELLO)


def encode_event(event: dict) -> bytes:
    """An event message: the event's dict as UTF-8 JSON."""
    return _header(EVENT) + json.dumps(event, separators=(",", ":")).encode()


def decode(data: bytes) -> Keyframe | Correction | End | Hello | EventMessage:
    """The message in `data`; MessageError saying what is wrong otherwise."""
    data = bytes(data)
    if len(data) < _HEADER.size:
        raise MessageError(f"{len(data)} bytes: shorter than the {_HEADER.size}-byte header.")
    magic, version, kind, reserved = _HEADER.unpack_from(data)
    if magic != MAGIC:
        raise MessageError(f"not an sgloc message (magic {magic!r}, need {MAGIC!r}).")
    if version != VERSION or reserved != 0:
        raise MessageError(f"message version {version} (reserved {reserved}): this sgloc reads "
                           f"version {VERSION}; update the sender or the server.")
    body = data[_HEADER.size:]
    decoder = _DECODERS.get(kind)
    if decoder is None:
        raise MessageError(f"unknown message kind {kind}.")
    return decoder(body)


def _fixed(body: bytes, s: struct.Struct, what: str) -> tuple:
    if len(body) != s.size:
        raise MessageError(f"{what}: {len(body)} body bytes, need {s.size}.")
    return s.unpack(body)


def _decode_keyframe(body: bytes) -> Keyframe:
    if len(body) < _KEYFRAME.size:
        raise MessageError(f"keyframe: {len(body)} body bytes, need at least {_KEYFRAME.size}.")
    seq, stamp_ns, *T, n = _KEYFRAME.unpack_from(body)
    if n > MAX_OBJECTS or len(body) != _KEYFRAME.size + 28 * n:
        raise MessageError(f"keyframe: {len(body)} body bytes do not hold the {n} objects it "
                           f"announces ({_KEYFRAME.size + 28 * n} needed).")
    T = np.array(T, np.float64).reshape(4, 4)
    pos = np.frombuffer(body, "<f8", 3 * n, _KEYFRAME.size).reshape(n, 3).astype(np.float64)
    lab = np.frombuffer(body, "<i4", n, _KEYFRAME.size + 24 * n).astype(np.int64)
    if stamp_ns < 0 or not np.isfinite(T).all() or not np.isfinite(pos).all():
        raise MessageError("keyframe: a negative stamp or a non-finite pose or position.")
    if not np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0]) or (lab < 0).any():
        raise MessageError("keyframe: the pose's last row is not 0 0 0 1, or a label < 0.")
    return Keyframe(seq, stamp_ns, T, pos, lab)


def _decode_correction(body: bytes) -> Correction:
    seq, held, rev, flags, *T = _fixed(body, _CORRECTION, "correction")
    T = np.array(T, np.float64).reshape(4, 4)
    if flags & ~(PLACED | FINISHED) or not np.isfinite(T).all():
        raise MessageError("correction: a non-finite transform or unknown flags.")
    return Correction(seq, held, rev, bool(flags & PLACED), T, bool(flags & FINISHED))


def _decode_end(body: bytes) -> End:
    seq, stamp_ns = _fixed(body, _END, "end")
    if stamp_ns < 0:
        raise MessageError("end: a negative stamp.")
    return End(seq, stamp_ns)


def _decode_hello(body: bytes) -> Hello:
    if body:
        raise MessageError(f"hello: {len(body)} body bytes, need 0.")
    return Hello()


def _decode_event(body: bytes) -> EventMessage:
    try:
        event = json.loads(body.decode()) if len(body) <= MAX_EVENT_BYTES else None
    except (UnicodeDecodeError, ValueError):
        event = None
    if not isinstance(event, dict):
        raise MessageError("event: the body is not a JSON object (or is too long).")
    return EventMessage(event)


_DECODERS = {KEYFRAME: _decode_keyframe, CORRECTION: _decode_correction, END: _decode_end,
             HELLO: _decode_hello, EVENT: _decode_event}
