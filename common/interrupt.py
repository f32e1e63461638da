"""A real Ctrl-C versus user code that raises ``KeyboardInterrupt`` or ``SystemExit`` itself.

Python turns SIGINT into ``KeyboardInterrupt``, but a plugin (a user's segmenter) can raise the
same exception, or call ``sys.exit()``, on its own. Either is a failure of the task that called
it, not a request to stop calnav, so calnav's boundary with user code (``user_code``) turns
them into ``UserCodeExit`` -- an ordinary exception, reported like any other -- unless SIGINT
really arrived: ``sigint_flag()`` installs, for its duration, a SIGINT handler that records the
signal (``sigint_received``) before raising ``KeyboardInterrupt`` as usual.

    with sigint_flag():            # the driver: the CLI, eval.runner.run_tasks
        ...
        with user_code("segmenter plugin 'mylab.seg:make'"):
            inner.segment(rgb, depth)   # sys.exit() here -> UserCodeExit; Ctrl-C -> KeyboardInterrupt

Only the main thread receives signals (and only it can install a handler); elsewhere
``sigint_flag`` is a no-op and a ``KeyboardInterrupt`` raised by user code there counts as the
user code's. Pool workers ignore SIGINT (``eval.backends.init_worker``): their driver stops them.
"""
from __future__ import annotations

import signal
import threading
from contextlib import contextmanager
from typing import Iterator

_received = threading.Event()   # set by the handler below: SIGINT arrived while it was installed
_depth = 0   # nesting depth of sigint_flag() in the main thread


class UserCodeExit(RuntimeError):
    """User code raised ``SystemExit`` (``sys.exit()``) or a ``KeyboardInterrupt`` of its own:
    a failure of the task that called it (the message says which and where)."""


def sigint_received() -> bool:
    """Whether SIGINT arrived while ``sigint_flag()`` was installed (since its outermost entry)."""
    return _received.is_set()


@contextmanager
def sigint_flag() -> Iterator[None]:
    """Record SIGINT for ``sigint_received`` while the block runs (it still raises
    ``KeyboardInterrupt``, through the handler that was installed before, if any). Nests; the
    outermost entry clears the record, its exit restores the previous handler."""
    global _depth
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    if _depth:
        _depth += 1
        try:
            yield
        finally:
            _depth -= 1
        return
    previous = signal.getsignal(signal.SIGINT)
    if not callable(previous):   # SIG_IGN (nothing to interrupt) or SIG_DFL (the process dies): left alone
        yield
        return

    def handler(signum, frame):
        _received.set()
        previous(signum, frame)   # Python's default handler raises KeyboardInterrupt

    _received.clear()
    signal.signal(signal.SIGINT, handler)
    _depth = 1
    try:
        yield
    finally:
        _depth = 0
        signal.signal(signal.SIGINT, previous)


@contextmanager
def user_code(what: str) -> Iterator[None]:
    """Run user code (``what`` names it in messages, e.g. "segmenter plugin 'mylab.seg:make'"):
    its ``SystemExit``, and a ``KeyboardInterrupt`` it raised itself, become ``UserCodeExit``;
    a real Ctrl-C (``sigint_received``) still propagates, and so do its ordinary exceptions."""
    try:
        yield
    except SystemExit as exc:
        call = "sys.exit()" if exc.code is None else f"sys.exit({exc.code!r})"
        raise UserCodeExit(f"{what} called {call}; a plugin reports a failure by raising an exception, calnav "
                           "does not exit for it") from exc
    except KeyboardInterrupt as exc:
        if sigint_received():
            raise
        raise UserCodeExit(f"{what} raised KeyboardInterrupt itself (no Ctrl-C was pressed)") from exc
