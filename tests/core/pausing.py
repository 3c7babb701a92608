"""A thread stopped at a chosen call, to force the interleaving a thread-rule test is about."""

from __future__ import annotations

import threading


class PauseAtCall:
    """A ``sys.settrace`` function: the thread that traces it stops at its first call of a
    function named ``name`` until :attr:`resume` is set (at most ``timeout`` s)."""

    def __init__(self, name: str, timeout: float = 10.0) -> None:
        self.name, self.timeout = name, timeout
        self.paused = threading.Event()
        self.resume = threading.Event()

    def __call__(self, frame, event, arg):
        if event == "call" and frame.f_code.co_name == self.name and not self.paused.is_set():
            self.paused.set()
            self.resume.wait(timeout=self.timeout)
        return None
