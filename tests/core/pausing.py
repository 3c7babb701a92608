"""Thread helpers of the thread tests: a thread stopped at a chosen call (to force the interleaving a
thread-rule test is about), and the beats of another thread while a call runs (does it let go of
the interpreter lock?)."""

from __future__ import annotations

import threading
import time


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


def beats_during(call) -> tuple[int, float]:
    """How many times another thread, beating every millisecond, ran while ``call()`` ran in this
    one, and how long the call took (s): about ``1000 × seconds`` when the call lets go of the
    interpreter lock, none when it holds the lock throughout."""
    beats: list[float] = []
    stop = threading.Event()

    def beat() -> None:
        while not stop.is_set():
            beats.append(time.perf_counter())
            time.sleep(0.001)

    other = threading.Thread(target=beat)
    other.start()
    try:
        time.sleep(0.01)
        start = time.perf_counter()
        call()
        end = time.perf_counter()
    finally:
        stop.set()
        other.join()
    return len([t for t in beats if start < t < end]), end - start
