"""Empirical uncertainty models against range and viewing angle (paper 2 §IV-C): their evaluation.

Paper 2 wants maps ``p_i = f^s(x, ℓ_i)`` (classification confidence) and ``Σ(ℓ_i^g) = f^g(x, ℓ_i)``
(geometric measurement covariance) learnt from data, with the sensor's range and viewing angle to
the object as the two inputs. This module holds the fitted models and evaluates them: the PAMS
planner (its sampling regions and information gain) and the SLAM backend (the noise of a shape
measurement) read the same models. Fitting them is :mod:`amslam.plugins.pams.uncertainty`'s
(``amslam characterise``).

* **confidence** — a multilayer perceptron (scikit-learn ``MLPRegressor``'s weights) of the
  expected confidence of a look at (range, angle).
* **geometric variance** — the smoothing spline of ln(variance) of each error component, over
  (range, angle) for angle-dependent classes (cuboids: vehicles), over range for range-only
  classes (cylinders: poles and trunks, paper 2 §V-A).

Predictions clamp the inputs to the range and angle the models were fitted on (no extrapolation).
Models are saved as one ``.npz`` of plain arrays plus a JSON header (never pickle): MLP weights and
input scaling, spline knots, coefficients and degrees. The MLP forward pass and the spline
evaluation (``scipy.interpolate.NdBSpline`` / ``splev``) are done from those arrays.
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = [
    "COMPONENTS",
    "DEFAULT_MODELS_PATH",
    "FORMAT",
    "POSITION_COMPONENTS",
    "ClassModel",
    "LogVarianceSpline",
    "Mlp",
    "UncertaintyModels",
]

FORMAT = "amslam-uncertainty-1"

#: The packaged default models, fitted with ``amslam characterise`` (see docs/pams.md): the PAMS
#: planner's and the SLAM backend's shape noise (docs/slam.md) use the same file.
DEFAULT_MODELS_PATH = Path(__file__).with_name("models") / "default.npz"

#: Components that are positions (the rest are dimensions), for the planner's region thresholds.
#: the geometric error components a characterisation measures per detection, in the object frame
COMPONENTS: tuple[str, ...] = ("x", "y", "length", "width")
POSITION_COMPONENTS = frozenset({"x", "y", "z"})


@dataclass
class Mlp:
    """A fitted ``MLPRegressor`` as plain arrays: standardised inputs, tanh/relu layers, identity output."""

    weights: list[np.ndarray]
    biases: list[np.ndarray]
    activation: str
    x_mean: np.ndarray
    x_scale: np.ndarray

    def __call__(self, X: np.ndarray) -> np.ndarray:
        """Outputs (N,) for inputs (N, d)."""
        h = (np.atleast_2d(np.asarray(X, float)) - self.x_mean) / self.x_scale
        for i, (W, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            h = h @ W + b
            if i < len(self.weights) - 1:
                h = np.tanh(h) if self.activation == "tanh" else np.maximum(h, 0.0)
        return h[:, 0]

    @staticmethod
    def fit(X: np.ndarray, y: np.ndarray, hidden: tuple[int, ...] = (16, 16), seed: int = 0) -> Mlp:
        """Fit an ``MLPRegressor`` (tanh, L-BFGS: small data) and keep its weights."""
        from sklearn.exceptions import ConvergenceWarning
        from sklearn.neural_network import MLPRegressor

        X = np.asarray(X, float)
        mean = X.mean(axis=0)
        scale = X.std(axis=0)
        scale[scale < 1e-9] = 1.0  # a constant input (a range-only class's angle) stays constant
        reg = MLPRegressor(
            hidden_layer_sizes=hidden,
            activation="tanh",
            solver="lbfgs",
            alpha=0.3,
            max_iter=1000,
            random_state=seed,
        )
        from threadpoolctl import threadpool_limits

        # one BLAS thread: tiny matrices, and oversubscribed threads on a shared machine cost 100×
        with warnings.catch_warnings(), threadpool_limits(1):
            # L-BFGS stopping at max_iter on a few hundred samples is a fitted model, not a failure
            warnings.simplefilter("ignore", ConvergenceWarning)
            reg.fit((X - mean) / scale, np.asarray(y, float))
        return Mlp(
            [np.asarray(w) for w in reg.coefs_], [np.asarray(b) for b in reg.intercepts_], "tanh", mean, scale
        )


@dataclass
class LogVarianceSpline:
    """A smoothing spline of ln(variance) against range (1-D) or (range, angle) (2-D)."""

    knots: list[np.ndarray]  # one knot vector per input
    coefficients: np.ndarray
    degrees: list[int]
    #: range of the fitted cell centres, m: outside, the curve is held at its edge value
    range_bounds: tuple[float, float] = (0.0, np.inf)
    #: ln-variances of the fitted cells: predictions are clipped to this band (no overshoot)
    value_bounds: tuple[float, float] = (-np.inf, np.inf)

    def __call__(self, rng: np.ndarray, angle: np.ndarray) -> np.ndarray:
        """ln(variance) at each (range, angle) pair."""
        return np.clip(
            self._eval(np.clip(np.asarray(rng, float).reshape(-1), *self.range_bounds), angle),
            *self.value_bounds,
        )

    def _eval(self, r: np.ndarray, angle: np.ndarray) -> np.ndarray:
        # scipy.interpolate (0.1 s) is imported when a model is evaluated, not when PAMS is listed
        from scipy.interpolate import NdBSpline, splev

        if len(self.knots) == 1:
            return np.asarray(splev(r, (self.knots[0], self.coefficients, self.degrees[0])), float)
        a = np.broadcast_to(np.asarray(angle, float).reshape(-1), r.shape)
        nx = len(self.knots[0]) - self.degrees[0] - 1
        ny = len(self.knots[1]) - self.degrees[1] - 1
        spline = NdBSpline(tuple(self.knots), self.coefficients.reshape(nx, ny), tuple(self.degrees))
        return np.asarray(spline(np.column_stack([r, a])), float)


@dataclass
class ClassModel:
    """Confidence and geometric variance models of one class."""

    class_name: str
    shape_model: str  # "cuboid" | "cylinder"
    components: list[str]
    angle_dependent: bool
    confidence_mlp: Mlp
    variance: list[LogVarianceSpline]
    range_bounds: tuple[float, float]
    angle_bounds: tuple[float, float] = (0.0, math.pi)
    samples: int = 0

    def _clamp(self, rng, angle) -> tuple[np.ndarray, np.ndarray]:
        r = np.clip(np.asarray(rng, float).reshape(-1), *self.range_bounds)
        a = np.asarray(angle, float).reshape(-1)
        a = (
            np.clip(np.broadcast_to(a, r.shape), *self.angle_bounds)
            if self.angle_dependent
            else np.zeros_like(r)
        )
        return r, a

    def confidence(self, rng: np.ndarray | float, angle: np.ndarray | float) -> np.ndarray:
        """Predicted (expected) classification confidence in [0, 1] at each (range, angle)."""
        r, a = self._clamp(rng, angle)
        return np.clip(self.confidence_mlp(np.column_stack([r, a])), 0.0, 1.0)

    def variances(self, rng: np.ndarray | float, angle: np.ndarray | float) -> np.ndarray:
        """Predicted measurement variances (N, len(components)) at each (range, angle)."""
        r, a = self._clamp(rng, angle)
        return np.exp(np.column_stack([s(r, a) for s in self.variance]))

    def covariance(self, rng: float, angle: float) -> np.ndarray:
        """Predicted measurement covariance (diagonal, components × components) of one look."""
        return np.diag(self.variances(rng, angle)[0])


@dataclass
class UncertaintyModels:
    """The models of every characterised class."""

    classes: dict[str, ClassModel] = field(default_factory=dict)
    meta: dict = field(default_factory=dict)

    def __getitem__(self, class_name: str) -> ClassModel:
        return self.classes[class_name]

    def __contains__(self, class_name: str) -> bool:
        return class_name in self.classes

    # -- persistence -----------------------------------------------------------------------
    def save(self, path: Path) -> None:
        """Write one ``.npz`` of plain arrays with a JSON header (loadable without pickle)."""
        arrays: dict[str, np.ndarray] = {}
        header: dict = {"format": FORMAT, "meta": self.meta, "classes": {}}
        for name, m in self.classes.items():
            key = f"c{len(header['classes'])}"
            header["classes"][name] = {
                "key": key,
                "shape_model": m.shape_model,
                "components": m.components,
                "angle_dependent": m.angle_dependent,
                "range_bounds": list(m.range_bounds),
                "angle_bounds": list(m.angle_bounds),
                "samples": m.samples,
                "activation": m.confidence_mlp.activation,
                "layers": len(m.confidence_mlp.weights),
                "spline_degrees": [s.degrees for s in m.variance],
                "spline_range_bounds": [list(s.range_bounds) for s in m.variance],
                "spline_value_bounds": [list(s.value_bounds) for s in m.variance],
            }
            mlp = m.confidence_mlp
            arrays[f"{key}.x_mean"], arrays[f"{key}.x_scale"] = mlp.x_mean, mlp.x_scale
            for i, (W, b) in enumerate(zip(mlp.weights, mlp.biases, strict=True)):
                arrays[f"{key}.W{i}"], arrays[f"{key}.b{i}"] = W, b
            for j, s in enumerate(m.variance):
                arrays[f"{key}.s{j}.c"] = s.coefficients
                for k, t in enumerate(s.knots):
                    arrays[f"{key}.s{j}.t{k}"] = t
        np.savez_compressed(Path(path), header=np.array(json.dumps(header)), **arrays)

    @staticmethod
    def load(path: Path | None = None) -> UncertaintyModels:
        """Read models written by :meth:`save` (default: the packaged models)."""
        path = DEFAULT_MODELS_PATH if path is None else Path(path)
        with np.load(path, allow_pickle=False) as f:
            header = json.loads(str(f["header"]))
            if header.get("format") != FORMAT:
                raise ValueError(f"{path}: not an uncertainty model file ({header.get('format')!r})")
            classes = {}
            for name, h in header["classes"].items():
                key = h["key"]
                mlp = Mlp(
                    [f[f"{key}.W{i}"] for i in range(h["layers"])],
                    [f[f"{key}.b{i}"] for i in range(h["layers"])],
                    h["activation"],
                    f[f"{key}.x_mean"],
                    f[f"{key}.x_scale"],
                )
                splines = [
                    LogVarianceSpline(
                        [f[f"{key}.s{j}.t{k}"] for k in range(len(deg))],
                        f[f"{key}.s{j}.c"],
                        list(deg),
                        tuple(h["spline_range_bounds"][j]),
                        tuple(h["spline_value_bounds"][j]),
                    )
                    for j, deg in enumerate(h["spline_degrees"])
                ]
                classes[name] = ClassModel(
                    name,
                    h["shape_model"],
                    list(h["components"]),
                    bool(h["angle_dependent"]),
                    mlp,
                    splines,
                    tuple(h["range_bounds"]),
                    tuple(h["angle_bounds"]),
                    int(h["samples"]),
                )
        return UncertaintyModels(classes, header.get("meta", {}))
