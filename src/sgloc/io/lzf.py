"""LZF (liblzf) decompression and a simple compressor, for PCD `binary_compressed` data.

Pure Python: map files are at most a few megabytes, where this takes well under a second.
"""

from __future__ import annotations

_MAX_OFFSET = 1 << 13  # back-references reach at most 8192 bytes back
_MAX_REF = 264  # longest back-reference (7 + 255 + 2 bytes)


class LZFError(ValueError):
    """The compressed stream is corrupt or does not expand to the announced size."""


def lzf_decompress(data: bytes, expected_size: int) -> bytes:
    """Expand an LZF stream that must yield exactly `expected_size` bytes."""
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        ctrl = data[i]
        i += 1
        if ctrl < 32:  # literal run of ctrl + 1 bytes
            length = ctrl + 1
            if i + length > n:
                raise LZFError("literal run past the end of the data")
            out += data[i : i + length]
            i += length
        else:  # back-reference
            length = ctrl >> 5
            if length == 7:
                if i >= n:
                    raise LZFError("back-reference cut off")
                length += data[i]
                i += 1
            if i >= n:
                raise LZFError("back-reference cut off")
            start = len(out) - ((ctrl & 0x1F) << 8) - data[i] - 1
            i += 1
            length += 2
            if start < 0:
                raise LZFError("back-reference before the start of the data")
            if start + length <= len(out):
                out += out[start : start + length]
            else:  # overlaps the bytes being written: a repeating pattern
                for k in range(length):
                    out.append(out[start + k])
        if len(out) > expected_size:
            raise LZFError(f"expands past the announced {expected_size} bytes")
    if len(out) != expected_size:
        raise LZFError(f"expands to {len(out)} bytes, the header announces {expected_size}")
    return bytes(out)


def lzf_compress(data: bytes) -> bytes:
    """A valid LZF stream of `data` (greedy matching on 3-byte prefixes)."""
    out, literal = bytearray(), bytearray()
    last_seen: dict[bytes, int] = {}

    def flush() -> None:
        if literal:
            out.append(len(literal) - 1)
            out.extend(literal)
            literal.clear()

    i, n = 0, len(data)
    while i < n:
        ref = None
        if i + 2 < n:
            key = data[i : i + 3]
            ref = last_seen.get(key)
            last_seen[key] = i
        if ref is not None and i - ref - 1 < _MAX_OFFSET:
            length = 3
            limit = min(_MAX_REF, n - i)
            while length < limit and data[ref + length] == data[i + length]:
                length += 1
            flush()
            offset, code = i - ref - 1, length - 2
            if code < 7:
                out.append((code << 5) | (offset >> 8))
            else:
                out.append((7 << 5) | (offset >> 8))
                out.append(code - 7)
            out.append(offset & 0xFF)
            i += length
            continue
        literal.append(data[i])
        i += 1
        if len(literal) == 32:
            flush()
    flush()
    return bytes(out)
