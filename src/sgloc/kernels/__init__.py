"""Compiled (numba) kernels of the hot loops, each with a plain numpy reference in its caller.

Importing this package is cheap: numba is imported, and each kernel compiled, only when a
kernel module is first imported (callers import them inside functions). Compiled code is cached
on disk (`cache=True`): next to the sources when that directory is writable, otherwise in numba's
per-user cache directory; `NUMBA_CACHE_DIR` overrides both.
"""
