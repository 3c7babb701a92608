"""The console amslam prints to, guarded against a reader that goes away.

``amslam run MISSION | head -1``: once ``head`` has its line it exits, and amslam's next write to
stdout fails (EPIPE). A robot in the air must not fall for that, nor a run lose its folder.
:func:`guarded` (the command line wraps every command in it) replaces ``sys.stdout`` and
``sys.stderr`` with wrappers that, on a broken pipe, point the stream at ``/dev/null`` and go on:
the command carries on to its normal end — a flight to its verdict, an experiment through all its
runs to its summary — printing nothing more there. Every :func:`when_closed` listener is told (a
run records ``stdout_closed`` in ``events.jsonl``), and the command line then exits 141.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
from collections.abc import Callable, Iterator
from typing import IO

_lock = threading.Lock()
#: the outputs (``stdout``, ``stderr``) whose reader went away, in the order they went
closed: list[str] = []
_listeners: list[Callable[[str], None]] = []


class _Guarded:
    """A text stream whose writes and flushes never raise BrokenPipeError (see the module)."""

    def __init__(self, stream: IO[str], name: str):
        self._stream = stream
        self._name = name

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            _gone(self._stream, self._name)
            return len(text)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except BrokenPipeError:
            _gone(self._stream, self._name)

    def __getattr__(self, name: str):  # isatty, fileno, encoding, ...: the stream's own
        return getattr(self._stream, name)


def _gone(stream: IO[str], name: str) -> None:
    # what is still buffered, and all that follows, goes to /dev/null: no second EPIPE, not even
    # from the interpreter's last flush at exit
    with contextlib.suppress(OSError, ValueError, AttributeError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, stream.fileno())
        os.close(devnull)
    with _lock:
        if name in closed:
            return
        closed.append(name)
        listeners = list(_listeners)
    for listener in listeners:
        with contextlib.suppress(Exception):  # a listener must not turn this into a failure
            listener(name)


def when_closed(listener: Callable[[str], None]) -> Callable[[], None]:
    """Call ``listener(name)`` when stdout or stderr loses its reader — at once for one already
    lost. Returns the function that stops the listening."""
    with _lock:
        _listeners.append(listener)
        already = list(closed)
    for name in already:
        with contextlib.suppress(Exception):
            listener(name)

    def stop() -> None:
        with _lock, contextlib.suppress(ValueError):
            _listeners.remove(listener)

    return stop


@contextlib.contextmanager
def guarded() -> Iterator[None]:
    """``sys.stdout`` and ``sys.stderr`` guarded (see the module) for the ``with`` block."""
    saved = sys.stdout, sys.stderr
    closed.clear()
    sys.stdout, sys.stderr = _Guarded(sys.stdout, "stdout"), _Guarded(sys.stderr, "stderr")
    try:
        yield
    finally:
        sys.stdout, sys.stderr = saved
