"""The console amslam prints to, guarded against a reader that goes away.

``amslam run MISSION | head -1``: once ``head`` has its line it exits, and amslam's next write to
stdout fails (EPIPE). A robot in the air must not fall for that, nor a run lose its folder.
:func:`guarded` (the command line wraps every command in it) replaces ``sys.stdout`` and
``sys.stderr`` with wrappers that, on a broken pipe, point the stream at ``/dev/null`` and go on:
the command carries on to its normal end — a flight to its verdict, an experiment through all its
runs to its summary — printing nothing more there. Every :func:`when_closed` listener is told (a
run records ``stdout_closed`` in ``events.jsonl``), and the command line then exits 141.

:func:`logging_to_stderr` sends log records — a run's status line, warnings, Python's warnings
(``logging.captureWarnings``) — to the guarded stderr at the level ``--quiet``, ``--verbose`` or
``--log-level`` chose.
"""

from __future__ import annotations

import contextlib
import logging
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


#: ``--log-level`` names, quietest last
LEVELS = ("debug", "info", "warning", "error", "critical")


class _Formatter(logging.Formatter):
    """Informational lines (a run's status line) as they are; other levels prefixed like the
    command line's own ``error:`` lines. A warning from Python's ``warnings`` (numpy's
    RuntimeWarning, say) keeps its first line — ``file:line: Category: message`` — unless
    ``verbose``, which adds the source line below it."""

    def __init__(self, verbose: bool):
        super().__init__()
        self.verbose = verbose

    def format(self, record: logging.LogRecord) -> str:
        text = record.getMessage()
        if record.name == "py.warnings" and not self.verbose:
            text = text.strip().splitlines()[0]
        if record.levelno == logging.INFO:
            return text
        prefix = record.levelname.lower()
        if self.verbose and record.name not in ("root", "py.warnings"):
            prefix += f": {record.name}"
        if record.exc_info and self.verbose:
            text += "\n" + self.formatException(record.exc_info)
        return f"{prefix}: {text.rstrip()}"


@contextlib.contextmanager
def logging_to_stderr(level: str) -> Iterator[None]:
    """For the ``with`` block: log records of ``level`` and above (a name of :data:`LEVELS`) to
    ``sys.stderr`` as it is now (the guarded stream), Python warnings among them.

    amslam's own loggers (``amslam.*``) follow ``level`` all the way down; other libraries' only
    from ``warning`` up, so that ``info`` does not print what a dependency chats about.
    """
    number = getattr(logging, level.upper())
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_Formatter(verbose=number <= logging.DEBUG))
    root, ours = logging.getLogger(), logging.getLogger("amslam")
    saved = root.level, ours.level
    root.addHandler(handler)
    root.setLevel(max(number, logging.WARNING))
    ours.setLevel(number)
    logging.captureWarnings(True)  # numpy's RuntimeWarning & co: --quiet silences them
    try:
        yield
    finally:
        logging.captureWarnings(False)
        root.removeHandler(handler)
        root.setLevel(saved[0])
        ours.setLevel(saved[1])
