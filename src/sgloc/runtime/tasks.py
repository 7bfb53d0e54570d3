"""The one task runner: a picklable function over a list of picklable tasks, run in this
process, on local worker processes or on a Dask cluster, results in the order of the tasks.
Trials (`sgloc.evaluation.trials`) and a fleet's pairwise localizations run through it."""

from __future__ import annotations

import os
import socket
import struct
import time
from collections.abc import Callable, Sequence
from concurrent.futures import as_completed
from typing import Any, TypeVar

from sgloc.errors import SglocError
from sgloc.runtime.workers import process_pool

Task = TypeVar("Task")
#: Called with the number of tasks just finished (for a progress bar).
Progress = Callable[[int], None]
#: Seconds to wait for a Dask scheduler to answer.
SCHEDULER_TIMEOUT_S = 15
#: Seconds to wait for a TCP connection to the scheduler and for its greeting.
PROBE_TIMEOUT_S = 4.0
#: Largest greeting a Dask scheduler sends (bytes; a real one is about 60).
_MAX_GREETING = 1 << 16


def run_all(
    tasks: Sequence[Task],
    fn: Callable[[Task], Any],
    workers: int | None = None,
    scheduler: Any = None,
    progress: Progress | None = None,
) -> list[Any]:
    """`fn` of each task (both picklable), in the order of `tasks`.

    workers: local processes (None: the number of CPUs; 0 or 1: in this process).
    scheduler: a Dask scheduler address ("tcp://host:8786") or a `distributed.Client`; when
        given, the tasks run on that cluster instead (its workers must see the same data paths).
    progress: called with the number of tasks just finished.
    """
    tasks = list(tasks)
    tick = progress or (lambda n: None)
    if scheduler is not None:
        return _run_dask(tasks, scheduler, tick, fn)
    if runs_here(len(tasks), workers, scheduler):
        rows = []
        for t in tasks:
            rows.append(fn(t))
            tick(1)
        return rows
    workers = (os.cpu_count() or 1) if workers is None else workers
    with process_pool(min(workers, len(tasks))) as pool:
        return _collect([pool.submit(fn, t) for t in tasks], as_completed, tick)


def runs_here(n_tasks: int, workers: int | None = None, scheduler: Any = None) -> bool:
    """Whether `run_all` runs `n_tasks` tasks in this process with these `workers` and
    `scheduler` (then a task may hold objects that do not travel well, a prepared map)."""
    if scheduler is not None:
        return False
    workers = (os.cpu_count() or 1) if workers is None else workers
    return workers <= 1 or n_tasks <= 1


def _collect(futures: list[Any], completed: Callable, tick: Progress) -> list[Any]:
    """The futures' results in their order, calling tick(1) as each completes (any order)."""
    index = {getattr(f, "key", f): i for i, f in enumerate(futures)}  # Dask futures by key
    rows: list[Any] = [None] * len(futures)
    for fut in completed(futures):
        rows[index[getattr(fut, "key", fut)]] = fut.result()
        tick(1)
    return rows


def _run_dask(tasks: list[Any], scheduler: Any, tick: Progress, fn: Callable) -> list[Any]:
    from sgloc.optional import require

    require("distributed", "dask", "--scheduler (running tasks on a Dask cluster)")
    from dask.distributed import Client
    from dask.distributed import as_completed as dask_completed

    own = not isinstance(scheduler, Client)
    if own:
        check_scheduler(str(scheduler))
    try:
        client = Client(scheduler, timeout=f"{SCHEDULER_TIMEOUT_S}s") if own else scheduler
    except (OSError, TimeoutError, ValueError, TypeError) as e:  # unreachable or malformed
        raise SglocError(
            f"cannot reach the Dask scheduler at {scheduler!r} ({e}); start one (e.g. "
            "`dask scheduler` and `dask worker ADDRESS`) or drop --scheduler to run locally."
        ) from None
    try:
        return _collect(client.map(fn, tasks, pure=False), dask_completed, tick)
    finally:
        if own:
            client.close()


def check_scheduler(address: str, timeout: float | None = None) -> None:
    """Check that a Dask scheduler answers at the TCP `address` ("tcp://host:port" or
    "host:port") within `timeout` seconds: it greets every new connection with a short framed
    message, which is read and checked before the address is handed to Dask (whose client
    would trust any length a non-Dask service sends, or wait forever for a silent one).
    SglocError naming the address otherwise. Other schemes (tls://, inproc://) are left to
    Dask."""
    hostport = _tcp_host_port(address)
    if hostport is None:
        return
    timeout = PROBE_TIMEOUT_S if timeout is None else timeout
    deadline = time.monotonic() + timeout
    fix = ("start one (e.g. `dask scheduler` and `dask worker ADDRESS`) or drop --scheduler to "
           "run locally.")
    try:
        with socket.create_connection(hostport, timeout=timeout) as conn:
            size = struct.unpack("Q", _read(conn, 8, deadline))[0]
            if not 16 <= size <= _MAX_GREETING:
                raise ValueError
            body = _read(conn, size, deadline)
    except TimeoutError:
        raise SglocError(f"the scheduler at {address!r} does not answer like a Dask scheduler "
                         f"(nothing within {timeout:g} s); check the address, or {fix}") from None
    except OSError as e:
        raise SglocError(f"cannot reach the Dask scheduler at {address!r} "
                         f"({e.strerror or e}); {fix}") from None
    except (ValueError, struct.error, EOFError):
        body = None
    if body is None or not _is_greeting(body):
        raise SglocError(f"the service at {address!r} is not a Dask scheduler (its first bytes "
                         f"are not a Dask greeting); check the address and port, or {fix}")


def _tcp_host_port(address: str) -> tuple[str, int] | None:
    """(host, port) of a TCP scheduler address; None for another scheme."""
    scheme, sep, rest = address.partition("://")
    if not sep:
        scheme, rest = "tcp", address
    if scheme != "tcp":
        return None
    host, colon, port = rest.rstrip("/").rpartition(":")
    if not colon or not port.isdigit() or not 0 < int(port) < 65536 or not host:
        raise SglocError(f"--scheduler {address!r}: give a Dask scheduler address such as "
                         "tcp://10.0.0.5:8786.")
    return host.strip("[]"), int(port)


def _read(conn: socket.socket, n: int, deadline: float) -> bytes:
    """Exactly `n` bytes from `conn` before `deadline`; EOFError if it closes, TimeoutError."""
    data = bytearray()
    while len(data) < n:
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError
        conn.settimeout(left)
        chunk = conn.recv(n - len(data))
        if not chunk:
            raise EOFError
        data += chunk
    return bytes(data)


def _is_greeting(body: bytes) -> bool:
    """True for Dask's framed handshake: a frame count, the frames' lengths adding up to the
    rest, and a msgpack map naming the pickle protocol."""
    (count,) = struct.unpack_from("Q", body)
    if not 1 <= count <= 64 or len(body) < 8 * (1 + count):
        return False
    lengths = struct.unpack_from(f"{count}Q", body, 8)
    if 8 * (1 + count) + sum(lengths) != len(body):
        return False
    return b"pickle-protocol" in body and b"compression" in body
