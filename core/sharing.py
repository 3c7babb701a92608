"""The thread rule's lock: a backend that two threads may call.

On a real vehicle several threads run (docs/architecture.md, "Threads"): the control thread
(perception step, behaviour tree, setpoints, the local map), the mapper and SLAM threads
(the global map's update; every SLAM call of perception), the planner and path threads, and the
detector thread. The planner thread queries the SLAM and mapping backends (``slc_candidates``,
``landmarks``, ``path_costs``) while the others integrate frames and detections into them, and
neither backend is written for that: gtsam's iSAM2 and a voxel map's cached search graph are
rewritten by queries as well as by updates. So the runtime hands every thread the same
:class:`Shared` wrapper of each of these backends, and every call into it holds the backend's
one re-entrant lock: a call sees the backend between two whole calls of another thread, never
in the middle of one.

A mapping backend whose local map is separate from its global map
(``Mapping.separate_local_map``) gets two locks: the local map's calls take one, every other call
the other. The control thread then checks setpoints against the local map while the mapper
thread updates the global map and its viewpoints (a tenth of a second and more per frame).

The cost is waiting, not copying: while the planner holds the map for a tour's path costs, a
control tick that integrates a frame waits for it (the vehicle holds its last setpoint). Copying
a map or a factor graph per plan would cost more than the wait, and a snapshot of either would
be stale by the time the plan is adopted anyway.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any, Generic, TypeVar

B = TypeVar("B")


#: the calls of a mapping backend that touch only its local map; ``LOCAL_WHEN_ASKED`` only with
#: ``local=True``
LOCAL_MAP_CALLS = frozenset({"integrate_local", "plan_local_path"})
LOCAL_WHEN_ASKED = frozenset({"states", "segment_free", "blocked"})


class Shared(Generic[B]):
    """A backend whose every method call holds its lock (attributes are read as they are)."""

    def __init__(self, backend: B):
        self._backend = backend
        self._methods: dict[str, Callable[..., Any]] = {}
        #: held by every call; a caller may hold it across several calls to see them as one
        self.lock = threading.RLock()
        #: held by the local map's calls instead, when the backend keeps that map apart
        self.local_lock = threading.RLock() if getattr(backend, "separate_local_map", False) else self.lock

    def _lock_for(self, name: str, kwargs: dict[str, Any]) -> threading.RLock:
        if self.local_lock is self.lock:
            return self.lock
        if name in LOCAL_MAP_CALLS or (name in LOCAL_WHEN_ASKED and kwargs.get("local", False)):
            return self.local_lock
        return self.lock

    @property
    def backend(self) -> B:
        """The backend itself, for single-threaded use after the threads have stopped."""
        return self._backend

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        value = getattr(self._backend, name)
        if not callable(value):
            return value
        method = self._methods.get(name)
        if method is None:
            lock_for = self._lock_for

            @functools.wraps(value)
            def method(*args: Any, **kwargs: Any) -> Any:
                with lock_for(name, kwargs):
                    return value(*args, **kwargs)

            self._methods[name] = method
        return method

    def __repr__(self) -> str:
        return f"Shared({self._backend!r})"


#: the backend kinds both the control thread and the planner thread call
SHARED_KINDS = ("slam", "mapping")


def share(backends: dict[str, Any]) -> dict[str, Any]:
    """The backends as the runtime's threads see them: the shared kinds wrapped in their locks."""
    return {kind: Shared(b) if kind in SHARED_KINDS else b for kind, b in backends.items()}


def finished(job: Callable[[], Any]) -> Future:
    """``job()`` run now, as a done future holding its result or its exception: what a threaded
    service hands back in the simulator, where everything runs inline (paths, plans, SLAM jobs)."""
    future: Future = Future()
    try:
        future.set_result(job())
    except Exception as exc:  # delivered through the future, like a threaded job's
        future.set_exception(exc)
    return future
