"""One compiled specialisation per kernel, whatever flags its array arguments carry.

numba compiles a function anew for every combination of argument types it meets, and a
read-only array (a graph's positions, a prepared map's buffers) is a different type from a
writable one with the same dtype, as a literal integer (`fit_model(..., 6, ...)` in another
kernel) is from an int64. Each combination was a compile of its own on first use (seconds for
the large kernels), a cache entry of its own, and a load of its own in a fresh process.

`kernel` compiles one type per argument instead: arrays read-only (those the kernel writes,
`writes`, stay writable) and integers without their literal value; a call with a writable
array or a literal runs that one (the same machine code: an array's flags only matter to
typing). The generated arithmetic is the same (read-only only forbids stores), so are the bits.

A compile, or a load from the cache, runs with SIGINT / SIGTERM held (`sgloc.runtime.interrupts`):
a signal raised inside numba's or LLVM's code would leave their objects half-built, and
freeing those can crash the interpreter; the signal is raised as the compile ends.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable

from numba import njit, types
from numba.core import sigutils

from sgloc.runtime import interrupts


def _plain(t, written: bool):
    """The one type `kernel` compiles an argument of type `t` as."""
    t = types.unliteral(t)
    if isinstance(t, types.Array) and t.mutable and not written:
        return t.copy(readonly=True)
    return t


def kernel(func: Callable | None = None, *, writes: tuple[str, ...] = ()):
    """`numba.njit(cache=True, nogil=True)` compiling one specialisation per kernel: array
    arguments read-only except the ones named in `writes`, integers without literal values
    (module docstring). Use as `@kernel` or `@kernel(writes=("out",))`."""

    def wrap(f: Callable):
        names = list(inspect.signature(f).parameters)
        unknown = set(writes) - set(names)
        if unknown:
            raise ValueError(f"{f.__qualname__}: writes names no argument: {sorted(unknown)}")
        written = tuple(n in writes for n in names)
        dispatcher = njit(cache=True, nogil=True)(f)
        compile_exact = dispatcher.compile

        def compile_plain(sig):
            args, _ = sigutils.normalize_signature(sig)
            plain = tuple(_plain(a, w) for a, w in zip(args, written, strict=True))
            with interrupts.held():
                entry = compile_exact(plain)
            if plain != tuple(args) and hasattr(dispatcher, "_insert"):
                # Calls from Python with these types run the same machine code (an array's
                # flags only matter to typing): entered in numba's dispatch table, they are
                # matched at once, never compiled. Calls from other kernels are typed against
                # `plain` by numba's own conversions. Without that (private) table entry, a
                # numba that lacks it sends such calls through this function each time: the
                # same code and bits, only slower.
                dispatcher._insert([a._code for a in args], entry, False)
            return entry

        dispatcher.compile = compile_plain
        return dispatcher

    return wrap(func) if func is not None else wrap
