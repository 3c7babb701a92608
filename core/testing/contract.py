"""What every contract kit shares: building a backend, its parameters and its run context.

A kit is a class of ``test_*`` methods. A plugin author subclasses it in a test module and
overrides :meth:`BackendContract.make_backend` (and :meth:`BackendContract.make_params` to tune
parameters); pytest collects the subclass (its name starts with ``Test``) and runs every inherited
test against the backend. The kits only assert what :mod:`amslam.interfaces` promises, so a
backend that passes them can be selected from a mission in place of a built-in one.
"""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

import numpy as np
import pydantic
import pytest
from pydantic.fields import FieldInfo

from amslam.backend_process import implementation
from amslam.interfaces import Backend, BackendParams, RunContext
from amslam.types import CameraModel, RobotSpec

#: A small depth camera for the synthetic scenes of the kits (fast, exact pixel centres).
CAMERA = CameraModel.from_fov(160, 120, 87.0, 58.0, min_range=0.3, max_range=5.0)


def documented(info: FieldInfo) -> bool:
    """A parameter has a description, or is a nested section whose model has a docstring."""
    if info.description:
        return True
    sub = info.annotation
    return isinstance(sub, type) and issubclass(sub, pydantic.BaseModel) and bool((sub.__doc__ or "").strip())


class BackendContract:
    """Lifecycle and parameter promises shared by every backend kind; override :meth:`make_backend`."""

    #: The abstract base the backend must derive from (set by each kind's kit).
    kind: ClassVar[type[Backend]] = Backend

    def make_backend(self) -> Backend:
        """A fresh, unconfigured backend."""
        raise NotImplementedError(f"override make_backend() to return your {self.kind.__name__} backend")

    def make_params(self, backend: Backend) -> BackendParams:
        """Parameters for the backend under test (its defaults unless overridden)."""
        return implementation(backend).Params()

    def make_context(self, tmp_path: Path, *, seed: int = 0) -> RunContext:
        """The run context the kit configures backends with (camera, robot, seeded generator)."""
        return RunContext(
            rng=np.random.default_rng(seed), run_dir=Path(tmp_path), camera=CAMERA, robot=RobotSpec()
        )

    def configured(self, tmp_path: Path, *, seed: int = 0) -> Backend:
        """A backend configured with :meth:`make_params` and :meth:`make_context`."""
        backend = self.make_backend()
        backend.configure(self.make_params(backend), self.make_context(tmp_path, seed=seed))
        return backend

    @pytest.fixture
    def backend(self, tmp_path: Path):
        """A configured backend, closed after the test."""
        backend = self.configured(tmp_path)
        yield backend
        backend.close()

    # ------------------------------------------------------------------ promises of every kind
    def test_is_a_backend_of_its_kind(self) -> None:
        backend = self.make_backend()
        assert isinstance(backend, self.kind), (
            f"{type(backend).__name__} must derive from {self.kind.__name__}"
        )

    def test_params_are_documented(self) -> None:
        params_cls = implementation(self.make_backend()).Params
        assert issubclass(params_cls, BackendParams)
        undocumented = [n for n, f in params_cls.model_fields.items() if not documented(f)]
        assert not undocumented, f"parameters without a description: {undocumented}"

    def test_params_have_defaults_and_forbid_unknown_keys(self) -> None:
        params_cls = implementation(self.make_backend()).Params
        params_cls()  # a mission may name the plugin without any parameter
        with pytest.raises(pydantic.ValidationError):
            params_cls.model_validate({"no_such_parameter_anywhere": 1})

    def test_close_twice(self, tmp_path: Path) -> None:
        backend = self.configured(tmp_path)
        backend.close()
        backend.close()
