"""Ctrl-C (SIGINT) and SIGTERM for the `sgloc` program: never lost, wherever they land.

A signal sets a flag that stays set until the program ends, then raises `Interrupted` in the
main thread so that every cleanup runs. Python swallows an exception raised inside a finaliser
(`__del__`) or a compiled library's callback; such a swallowed interruption is raised again a
moment later, outside it (a signal during an import is raised after it, as one inside a
finaliser), and writes are committed only after `check()` finds no signal (the
flag, or a signal held back by a signal mask), so a lost raise still ends the run with nothing
written. Before `install()` (while the program imports its modules) a signal only sets the flag.
"""

from __future__ import annotations

import signal
import sys

SIGNALS = (signal.SIGINT, signal.SIGTERM)

#: The process's interruption state: the first signal received (0: none), whether a signal
#: raises (after `install`), whether it was raised (later signals then only set the flag, so
#: that the cleanup runs undisturbed), the hook replaced by `install`, and the depth of
#: `hold` with the signal mask before the outermost, and whether a raise again is on its way.
_STATE: dict = {"signum": 0, "raising": False, "raised": False, "unraisable": None,
                "held": 0, "mask": set(), "again": False}


class Interrupted(BaseException):
    """Ctrl-C (SIGINT) or SIGTERM: raised in the main thread so that every cleanup runs (no
    half-written output stays). A BaseException but no KeyboardInterrupt, which the command
    framework would turn into a silent exit code."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _in_finaliser(frame) -> bool:
    """True if `frame` (or a caller, a few levels up) is a finaliser, where a raise is lost."""
    depth = 0
    while frame is not None and depth < 12:
        code = frame.f_code
        if code.co_name == "__del__" or code is _on_unraisable.__code__ or (
            code.co_name == "__call__" and code.co_filename.endswith("weakref.py")
        ):
            return True
        frame, depth = frame.f_back, depth + 1
    return False


def _importing(frame) -> bool:
    """True if `frame` runs inside an import (the import machinery is among its callers): a
    raise there can land in a compiled module's initialisation, which turns it into an
    ImportError and may leave the interpreter unable to finalise."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib._bootstrap"):
            return True
        frame = frame.f_back
    return False


def _on_signal(signum: int, frame) -> None:
    if not _STATE["signum"]:
        _STATE["signum"] = signum
    if not _STATE["raising"] or _STATE["raised"] or _STATE["held"]:
        return
    if _in_finaliser(frame) or _importing(frame):
        _again()
        return
    _STATE["raised"] = True
    raise Interrupted(_STATE["signum"])


def _again(delay: float = 0.005) -> None:
    """Raise the recorded interruption in the main thread in `delay` s (outside a finaliser)."""
    import _thread
    import threading

    if _STATE["again"]:  # one is on its way
        return

    def fire() -> None:
        _STATE["again"] = False
        if _STATE["raising"] and _STATE["signum"] and not _STATE["raised"]:
            _thread.interrupt_main(_STATE["signum"])

    _STATE["again"] = True
    timer = threading.Timer(delay, fire)
    timer.daemon = True
    timer.start()


def _on_unraisable(unraisable) -> None:
    """An interruption raised where Python cannot propagate it (a finaliser, a compiled
    callback): not printed, raised again shortly. After a signal, a finaliser's error is not
    printed either: it is the cleanup of an object the signal left half-built (a compiled
    library's), in a run that is being abandoned. Anything else as before."""
    if isinstance(unraisable.exc_value, (Interrupted, KeyboardInterrupt)):
        _STATE["raised"] = False
        _again()
        return
    if _STATE["signum"]:
        return
    previous = _STATE["unraisable"] or sys.__unraisablehook__
    previous(unraisable)


def install_early() -> None:
    """Signals only set the flag from now on (the program's start-up, in the main thread)."""
    try:
        for signum in SIGNALS:
            signal.signal(signum, _on_signal)
    except ValueError:  # not the main thread: signals are not handled there
        pass


def install() -> dict:
    """Signals set the flag and raise `Interrupted` from now on; return the handlers replaced
    (for `uninstall`). In the main thread only (elsewhere: nothing changes)."""
    previous: dict = {}
    if not _main_thread():
        return previous
    for signum in SIGNALS:
        previous[signum] = signal.signal(signum, _on_signal)
    if sys.unraisablehook is not _on_unraisable:
        _STATE["unraisable"] = sys.unraisablehook
        sys.unraisablehook = _on_unraisable
    _STATE["raising"] = True
    return previous


def uninstall(previous: dict) -> None:
    """Restore the handlers `install` replaced; release every hold, dropping the signals held
    back (they were reported); forget the signal received."""
    _STATE["raising"] = False
    if _STATE["held"] and _masks():
        try:
            while signal.sigtimedwait(SIGNALS, 0) is not None:
                pass
        except (OSError, ValueError):
            pass
        signal.pthread_sigmask(signal.SIG_SETMASK, _STATE["mask"])
    _STATE["held"] = 0
    for signum, handler in previous.items():
        if handler is not None:
            signal.signal(signum, handler)
    if sys.unraisablehook is _on_unraisable:
        sys.unraisablehook = _STATE["unraisable"] or sys.__unraisablehook__
    _STATE["signum"], _STATE["raised"] = 0, False


def ignore() -> None:
    """SIGINT / SIGTERM are ignored from now on (the program's exit: its outcome is known)."""
    try:
        for signum in SIGNALS:
            signal.signal(signum, signal.SIG_IGN)
    except ValueError:  # not the main thread
        pass


def in_chain(e: BaseException) -> Interrupted | None:
    """The interruption that caused `e` (a compiled library that turned it into an ImportError
    or SystemError), if any."""
    seen: set[int] = set()
    while e is not None and id(e) not in seen:
        if isinstance(e, Interrupted):
            return e
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return None


def received() -> int:
    """The signal received so far (also one held back by a signal mask); 0 when none."""
    if _STATE["signum"]:
        return _STATE["signum"]
    if hasattr(signal, "sigpending"):
        pending = signal.sigpending() & set(SIGNALS)
        if pending:
            return min(pending)
    return 0


def check() -> None:
    """Raise `Interrupted` if a signal was received (the last check before a commit)."""
    signum = received() if _STATE["raising"] else 0
    if signum:
        _STATE["raised"] = True
        raise Interrupted(signum)


def _main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


def _masks() -> bool:
    return _main_thread() and hasattr(signal, "pthread_sigmask")


def hold() -> None:
    """From now on until `release`, SIGINT / SIGTERM are only recorded (and, in the main
    thread, held back by the signal mask). Holds nest."""
    if not _masks():
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, set(SIGNALS))
    if not _STATE["held"]:
        _STATE["mask"] = old
    _STATE["held"] += 1


def release() -> None:
    """Undo one `hold`; at the last, a signal received meanwhile raises `Interrupted` (after
    `install`; otherwise the handler in place handles it as the mask is lifted)."""
    if not _masks() or not _STATE["held"]:
        return
    _STATE["held"] -= 1
    if _STATE["held"]:
        return
    signal.pthread_sigmask(signal.SIG_SETMASK, _STATE["mask"])
    if _STATE["raising"] and _STATE["signum"] and not _STATE["raised"]:
        _STATE["raised"] = True
        raise Interrupted(_STATE["signum"])


class held:
    """`with held():` SIGINT / SIGTERM wait for the end of the block (a signal received
    meanwhile is handled as the block ends): for short steps that must not stop half-way."""

    def __enter__(self) -> None:
        hold()

    def __exit__(self, *exc) -> None:
        release()
