"""A backend in a process of its own, for backends whose calls hold the interpreter lock for long.

Why a process: gtsam's Python bindings (like most pybind11 bindings) hold the interpreter lock
(GIL) for the whole of each C++ call. On a real vehicle the SLAM thread's marginal covariances
(``gtsam.Marginals`` over 2000 key poses: 0.2–0.4 s in one call), the planner's information gain
and landmark marginals each stopped the control thread for that long: no lock arrangement or
switch interval lets another thread run inside a C++ call that does not let go (docs/flight.md,
"Session 31": the late control ticks grew with the graph). A child process has its own
interpreter, so its calls cost the control thread nothing but the pickling of their arguments
and results.

A backend asks for it with ``own_process = True`` (:class:`amslam.interfaces.Backend`); the
runner honours it on a real vehicle only: in the simulator time stops while a module computes, so
a process would cost time and change nothing.

The child is a fresh interpreter (not a fork: a fork of a process with running threads can
inherit a held lock). It builds the backend from its class (pickled by reference: its module must
be importable), runs in a session of its own and ignores SIGINT and SIGTERM (the parent lands the
vehicle and then closes it; the run's summary still needs SLAM's key poses), and ends when the
parent closes it or its end of the pipe goes away. The backend's ``context.emit`` events
come back with each reply and are emitted in the parent, on the calling thread.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import multiprocessing.connection
import pickle
import signal
import subprocess
import sys
import threading
import traceback
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from amslam.interfaces import Backend, BackendParams, RunContext, Slam
from amslam.types import (
    Detection,
    KeyPose,
    Landmark,
    LoopClosureResult,
    Odometry,
    PoseUncertainty,
    SlcCandidate,
    SlcGainModel,
)

__all__ = ["BackendProcess", "BackendProcessError", "SlamProcess", "implementation"]

#: how long a closing child may take to close its backend before it is terminated (s)
CLOSE_TIMEOUT = 10.0


class BackendProcessError(RuntimeError):
    """The child process of a backend is gone (it crashed or was killed)."""


def implementation(backend: Backend) -> type:
    """The class that does the work: a backend's own, or the one a process runs for it."""
    return getattr(backend, "backend_class", type(backend))


@dataclasses.dataclass(frozen=True)
class _KeyPoseArrays:
    """A list of key poses as four arrays, unpickled in four short calls: a list of 2000
    ``KeyPose`` objects is unpickled in one call that holds the interpreter (4 ms here, 0.04 ms
    as arrays; more on a flight computer), and the SLAM thread fetches it after every key pose."""

    ids: np.ndarray
    stamps: np.ndarray
    T_world_body: np.ndarray
    distances: np.ndarray

    @classmethod
    def of(cls, keyposes: Sequence[KeyPose]) -> _KeyPoseArrays:
        return cls(
            np.array([k.id for k in keyposes], dtype=np.int64),
            np.array([k.stamp for k in keyposes], dtype=float),
            np.array([k.T_world_body for k in keyposes], dtype=float).reshape(-1, 4, 4),
            np.array([k.distance for k in keyposes], dtype=float),
        )

    def keyposes(self) -> list[KeyPose]:
        return [
            KeyPose(int(i), float(s), T, float(d))
            for i, s, T, d in zip(self.ids, self.stamps, self.T_world_body, self.distances, strict=True)
        ]


def _pack(result: Any) -> Any:
    if isinstance(result, list) and result and all(isinstance(k, KeyPose) for k in result):
        return _KeyPoseArrays.of(result)
    return result


def _unpack(result: Any) -> Any:
    return result.keyposes() if isinstance(result, _KeyPoseArrays) else result


def _serve(conn: Any) -> None:
    """The child: build the backend, then answer calls until told to close or the parent is gone."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    sys.path[:] = conn.recv()  # the parent's: its plugins import here as they did there
    events: list[tuple[str, dict]] = []
    backend, after_each, name = None, None, ""
    try:
        while True:
            try:
                message = conn.recv()
            except (EOFError, OSError):  # the parent is gone
                return
            except Exception as exc:  # noqa: BLE001 — it could not be unpickled here (an import)
                conn.send(("error", _picklable(exc), traceback.format_exc(), []))
                continue
            name, args, kwargs = message
            try:
                if name == "configure":
                    backend_class, after_each, params, context = args
                    context = dataclasses.replace(context, emit=lambda event, **f: events.append((event, f)))
                    backend = backend_class()
                    backend.configure(params, context)
                    result = None
                else:
                    result = _pack(getattr(backend, name)(*args, **kwargs))
                status = getattr(backend, after_each)() if after_each else None
                reply = ("ok", result, status, list(events))
            except Exception as exc:  # noqa: BLE001 — handed to the caller in the parent
                reply = ("error", _picklable(exc), traceback.format_exc(), list(events))
            events.clear()
            conn.send(reply)
            if name == "close":
                return
    finally:
        if backend is not None and name != "close":  # the parent went away without closing it
            backend.close()


def _picklable(exc: Exception) -> Exception:
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:  # noqa: BLE001 — its type and text are what the caller needs
        return RuntimeError(f"{type(exc).__name__}: {exc}")


class BackendProcess:
    """The parent's end: a backend of class ``backend_class`` in a child process, called over a
    pipe. Calls from several threads take turns (the child runs one at a time, like a
    :class:`amslam.sharing.Shared` backend). ``after_each`` names a method whose answer comes back
    with every reply (:attr:`status`): SLAM's correction, read without a call of its own."""

    def __init__(self, kind: str, backend_class: type, *, after_each: str | None = None):
        self.kind, self.backend_class, self.after_each = kind, backend_class, after_each
        self.status: Any = None
        self._emit: Callable[..., None] = lambda *a, **k: None
        self._lock = threading.Lock()
        self._process: subprocess.Popen | None = None
        self._conn: Any = None
        self._closed = False

    def configure(self, params: BackendParams, context: RunContext) -> None:
        """Start the child and build and configure the backend there (its errors are raised here)."""
        try:
            pickle.dumps((self.backend_class, params, dataclasses.replace(context, emit=None)))
        except Exception as exc:
            raise ValueError(
                f"{self.backend_class.__name__} cannot run in a process of its own: it, its "
                f"parameters or its run context cannot be sent there ({type(exc).__name__}: {exc})"
            ) from exc
        self._emit = context.emit
        # A fresh interpreter (`python -m amslam.backend_process FD`) rather than
        # multiprocessing's spawn, which re-runs the parent's main script: a user's script that
        # flies a mission without an `if __name__ == "__main__"` guard would start its flight again.
        self._conn, child = multiprocessing.Pipe()
        self._process = subprocess.Popen(
            [sys.executable, "-m", "amslam.backend_process", str(child.fileno())],
            pass_fds=(child.fileno(),),
            stdin=subprocess.DEVNULL,
            start_new_session=True,  # a Ctrl-C at the terminal is the parent's to handle
        )
        child.close()
        self._conn.send(list(sys.path))
        context = dataclasses.replace(context, emit=None)
        self.call("configure", self.backend_class, self.after_each, params, context)

    def call(self, name: str, *args: Any, **kwargs: Any) -> Any:
        """``backend.name(*args, **kwargs)`` in the child: its result, or its exception raised here."""
        with self._lock:
            if self._closed or self._process is None:
                raise BackendProcessError(f"the {self.kind} process was closed; {name}() cannot be called")
            try:
                self._conn.send((name, args, kwargs))
                reply = self._conn.recv()
            except (EOFError, OSError) as exc:
                self._closed = True
                raise BackendProcessError(
                    f"the {self.kind} process ({self.backend_class.__name__}) ended during {name}() "
                    f"with exit code {self._exit_code(1.0)}"
                ) from exc
            outcome, value, detail, events = reply
            if outcome == "ok":  # under the lock: a later call's status never precedes an earlier one's
                self.status = detail
        for event, fields in events:
            self._emit(event, **fields)
        if outcome == "error":
            value.add_note(f"in the {self.kind} process:\n{detail}")
            raise value
        return _unpack(value)

    def close(self) -> None:
        """Close the backend in the child and end it; safe to call twice."""
        if self._closed or self._process is None:
            self._closed = True
            return
        try:
            self.call("close")
        except Exception:  # noqa: BLE001 — closing what is already gone
            pass
        finally:
            self._closed = True
            if self._exit_code(CLOSE_TIMEOUT) is None:
                self._process.kill()
                self._process.wait()
            self._conn.close()

    def _exit_code(self, timeout: float) -> int | None:
        try:
            return self._process.wait(timeout)
        except subprocess.TimeoutExpired:
            return None


class SlamProcess(Slam):
    """A SLAM backend in a process of its own (:class:`BackendProcess`). ``T_world_odom`` is the
    correction that came back with the latest call: every change of it is made by a call."""

    def __init__(self, backend_class: type[Slam]):
        self.backend_class = backend_class
        self._process = BackendProcess("slam", backend_class, after_each="T_world_odom")

    def configure(self, params: BackendParams, context: RunContext) -> None:
        self._process.configure(params, context)

    def close(self) -> None:
        self._process.close()

    def add_odometry(self, odom: Odometry) -> bool:
        return self._process.call("add_odometry", odom)

    def add_detections(self, odom: Odometry, T_body_cam: np.ndarray, detections: list[Detection]) -> None:
        self._process.call("add_detections", odom, T_body_cam, detections)

    def T_world_odom(self) -> np.ndarray:
        return np.array(self._process.status, dtype=float)

    def keyposes(self) -> list[KeyPose]:
        return self._process.call("keyposes")

    def landmarks(self) -> list[Landmark]:
        return self._process.call("landmarks")

    def object_map(self) -> list[Landmark]:
        return self._process.call("object_map")

    def uncertainty(self) -> tuple[float, float]:
        return self._process.call("uncertainty")

    def try_loop_closure(
        self, odom: Odometry, T_body_cam: np.ndarray, detections: list[Detection]
    ) -> LoopClosureResult:
        return self._process.call("try_loop_closure", odom, T_body_cam, detections)

    def slc_candidates(self, sensing_range: float) -> list[SlcCandidate]:
        return self._process.call("slc_candidates", sensing_range)

    def information_gain(self, keypose_ids: list[int], travel_distances: list[float]) -> np.ndarray:
        return self._process.call("information_gain", keypose_ids, travel_distances)

    def slc_gain_model(self, keypose_ids: list[int]) -> SlcGainModel | None:
        return self._process.call("slc_gain_model", keypose_ids)

    def pose_uncertainty(self) -> PoseUncertainty | None:
        return self._process.call("pose_uncertainty")


if __name__ == "__main__":
    # the module's own classes must be pickled under its name, not as __main__'s
    from amslam.backend_process import _serve as serve

    serve(multiprocessing.connection.Connection(int(sys.argv[1])))
