"""Empirical uncertainty models against range and viewing angle (paper 2 §IV-C).

Paper 2 wants maps ``p_i = f^s(x, ℓ_i)`` (classification confidence) and ``Σ(ℓ_i^g) = f^g(x, ℓ_i)``
(geometric measurement covariance) learnt from data, with the sensor's range and viewing angle to
the object as the two inputs. Following the paper:

* **confidence** — a multilayer perceptron (scikit-learn ``MLPRegressor``) regressing the
  confidence of each characterisation frame on (range, angle). A frame where the detector missed
  the object counts as confidence 0, so the prediction is the *expected* confidence of a look,
  which folds the miss rate into the "high-confidence region".
* **geometric variance** — range and angle are discretised; in every cell with enough samples
  the variance of each error component is the mean squared error against ground truth (bias
  included: a biased fit is as bad as a noisy one); a smoothing spline is fitted to the log of
  these cell variances (log: positive predictions, and the error of a sample variance is roughly
  constant in log space, ``sd(ln s²) ≈ √(2/(n−1))``, which gives the spline's weights and lets the
  smoothing factor be the number of cells). Angle-dependent classes (cuboids: vehicles) get a
  bicubic ``SmoothBivariateSpline`` over (range, angle); range-only classes (cylinders: poles and
  trunks, paper 2 §V-A) a cubic ``UnivariateSpline`` over range.

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

FORMAT = "amslam-uncertainty-1"

#: The packaged default models, fitted with ``amslam characterise`` (see docs/pams.md).
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


# -- fitting ---------------------------------------------------------------------------------------


def cell_variances(
    rng: np.ndarray,
    angle: np.ndarray | None,
    errors: np.ndarray,
    range_bin: float,
    angle_bin: float,
    min_count: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Mean squared error per (range, angle) cell with at least ``min_count`` samples.

    Returns:
        (range centres, angle centres, variances, counts) of the kept cells; angle centres are 0
        when ``angle`` is None (range-only binning).
    """
    r_idx = np.floor(rng / range_bin).astype(int)
    a_idx = (
        np.zeros_like(r_idx)
        if angle is None
        else np.minimum(np.floor(angle / angle_bin), math.pi / angle_bin - 1).astype(int)
    )
    cells: dict[tuple[int, int], list[float]] = {}
    for i, j, e in zip(r_idx.tolist(), a_idx.tolist(), errors.tolist(), strict=True):
        cells.setdefault((i, j), []).append(e)
    out = []
    for (i, j), es in sorted(cells.items()):
        if len(es) >= min_count:
            e = np.asarray(es)
            out.append(
                (
                    (i + 0.5) * range_bin,
                    0.0 if angle is None else (j + 0.5) * angle_bin,
                    float(np.mean(e**2)),
                    len(es),
                )
            )
    if not out:
        return np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0, dtype=int)
    a = np.array(out)
    return a[:, 0], a[:, 1], a[:, 2], a[:, 3].astype(int)


def _pooled_kurtosis(rng, angle, errors, range_bin, angle_bin, rc, ac, var) -> float:
    """Kurtosis E[(e/σ)⁴] of the errors, each standardised by the variance of its cell."""
    lookup = {
        (int(r // range_bin), 0 if angle is None else int(a // angle_bin)): v
        for r, a, v in zip(rc, ac, var, strict=True)
    }
    r_idx = np.floor(rng / range_bin).astype(int)
    a_idx = (
        np.zeros_like(r_idx)
        if angle is None
        else np.minimum(np.floor(angle / angle_bin), math.pi / angle_bin - 1).astype(int)
    )
    z4 = [
        e**4 / lookup[(i, j)] ** 2
        for i, j, e in zip(r_idx.tolist(), a_idx.tolist(), errors.tolist(), strict=True)
        if (i, j) in lookup and lookup[(i, j)] > 0
    ]
    return float(np.mean(z4)) if z4 else 3.0


def fit_log_variance(
    rng: np.ndarray,
    angle: np.ndarray | None,
    errors: np.ndarray,
    range_bounds: tuple[float, float],
    *,
    range_bin: float = 1.0,
    angle_bin: float = math.radians(15.0),
    min_count: int = 5,
) -> LogVarianceSpline:
    """Smoothing spline of ln(cell variance) against range (and angle).

    Raises:
        ValueError: fewer than two cells hold ``min_count`` samples.
    """
    from scipy.interpolate import SmoothBivariateSpline, UnivariateSpline

    rc, ac, var, n = cell_variances(rng, angle, errors, range_bin, angle_bin, min_count)
    while len(rc) < 8 and range_bin < np.ptp(rng) / 4:
        # sparse data (a class seen from few places): coarser cells, until a curve can be fitted
        range_bin, angle_bin = 2.0 * range_bin, min(2.0 * angle_bin, math.pi / 2)
        rc, ac, var, n = cell_variances(rng, angle, errors, range_bin, angle_bin, min_count)
    if len(rc) < 2:
        raise ValueError(f"only {len(rc)} cells with ≥ {min_count} samples: fly more frames")
    z = np.log(np.maximum(var, 1e-8))
    # sd(ln s²) ≈ √((κ − 1)/n) for errors of kurtosis κ (κ = 3, Gaussian: √(2/n)); real fit errors
    # are heavy-tailed (a flipped box axis), so κ is pooled from the data, each error standardised
    # by its own cell's variance
    kappa = _pooled_kurtosis(rng, angle, errors, range_bin, angle_bin, rc, ac, var)
    w = np.sqrt(np.maximum(n, 2) / max(kappa - 1.0, 2.0))
    # cell centres may lie just outside the samples' span: the spline's interval covers both
    lo, hi = min(range_bounds[0], float(rc.min())), max(range_bounds[1], float(rc.max()))
    bounds_r = (float(rc.min()), float(rc.max()))
    bounds_z = (float(z.min()), float(z.max()))
    if angle is None:
        k = min(3, len(rc) - 1)
        s = UnivariateSpline(rc, z, w=w, k=k, s=len(rc), bbox=[lo, hi], ext=3)
        t, c, deg = s._eval_args  # the (t, c, k) tuple splev evaluates
        return LogVarianceSpline([np.asarray(t)], np.asarray(c), [int(deg)], bounds_r, bounds_z)
    n_r, n_a = len(np.unique(rc)), len(np.unique(ac))
    kx, ky = min(3, n_r - 1), min(3, n_a - 1)
    while (kx + 1) * (ky + 1) > len(rc) and max(kx, ky) > 1:
        kx, ky = max(1, kx - 1), max(1, ky - 1)
    if min(kx, ky) < 1 or (kx + 1) * (ky + 1) > len(rc):
        # too few cells over the angles for a surface: pool the angles, a curve over range
        return fit_log_variance(
            rng, None, errors, range_bounds, range_bin=range_bin, angle_bin=angle_bin, min_count=min_count
        )
    smooth = float(len(rc))
    for _ in range(8):
        # FITPACK stops adding knots at its storage limit and then warns that s was not reached;
        # that spline interpolates noise, so relax s (×2) until the fit meets it
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            s2 = SmoothBivariateSpline(rc, ac, z, w=w, bbox=[lo, hi, 0.0, math.pi], kx=kx, ky=ky, s=smooth)
        if not caught:
            break
        smooth *= 2.0
    tx, ty = s2.get_knots()
    return LogVarianceSpline(
        [np.asarray(tx), np.asarray(ty)], np.asarray(s2.get_coeffs()), [kx, ky], bounds_r, bounds_z
    )


def fit_models(
    samples,
    *,
    range_bin: float = 1.0,
    angle_bin_deg: float = 15.0,
    min_count: int = 5,
    hidden: tuple[int, ...] = (16, 16),
    seed: int = 0,
    min_component_share: float = 0.5,
) -> UncertaintyModels:
    """Fit the confidence MLP and the variance splines of every class in ``samples``.

    Args:
        samples: :class:`amslam.apps.characterise.Samples` (or anything with its fields).
        range_bin: width of the range cells of the variance estimates, m.
        angle_bin_deg: width of the angle cells, degrees.
        min_count: fewest samples for a cell's variance to be used.
        hidden: hidden layer sizes of the confidence MLP.
        seed: seed of the MLP's initial weights.
        min_component_share: an error component is modelled when at least this share of the
            detections measured it (cuboid dimensions need a cuboid fit).
    """
    models = UncertaintyModels(
        meta={"range_bin": range_bin, "angle_bin_deg": angle_bin_deg, "min_count": min_count}
    )
    for name in sorted(samples.models):
        s = samples.of(name)
        if s.detected.sum() < 10:
            continue  # never (or hardly ever) detected: nothing to model
        kind = s.models[name]
        angle_dependent = kind == "cuboid"
        angle = s.angle if angle_dependent else np.zeros_like(s.range)
        lo, hi = float(s.range.min()), float(s.range.max())
        mlp = Mlp.fit(np.column_stack([s.range, angle]), s.confidence, hidden, seed)
        det = s.detected
        comps, splines = [], []
        for k, comp in enumerate(COMPONENTS):
            e = s.errors[det, k]
            ok = np.isfinite(e)
            if ok.sum() < max(1, min_component_share * det.sum()):
                continue
            splines.append(
                fit_log_variance(
                    s.range[det][ok],
                    s.angle[det][ok] if angle_dependent else None,
                    e[ok],
                    (lo, hi),
                    range_bin=range_bin,
                    angle_bin=math.radians(angle_bin_deg),
                    min_count=min_count,
                )
            )
            comps.append(comp)
        models.classes[name] = ClassModel(
            name, kind, comps, angle_dependent, mlp, splines, (lo, hi), (0.0, math.pi), len(s)
        )
    return models


def plot_models(models: UncertaintyModels, path: Path, samples=None) -> None:
    """PNG of each class: predicted confidence and geometric entropy against range and angle."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(models.classes)
    fig, axes = plt.subplots(len(names), 3, figsize=(15, 3.6 * len(names)), squeeze=False)
    for row, name in zip(axes, names, strict=True):
        m = models[name]
        r = np.linspace(*m.range_bounds, 80)
        a = np.linspace(0.0, math.pi, 60)
        R, A = np.meshgrid(r, a)
        conf = m.confidence(R.ravel(), A.ravel()).reshape(R.shape)
        var = m.variances(R.ravel(), A.ravel())
        ent = 0.5 * np.log(var).sum(axis=1).reshape(R.shape)
        if m.angle_dependent:
            im0 = row[0].pcolormesh(r, np.degrees(a), conf, shading="auto", vmin=0, vmax=1)
            im1 = row[1].pcolormesh(r, np.degrees(a), ent, shading="auto", cmap="magma")
            for ax, im, title in ((row[0], im0, "confidence"), (row[1], im1, "geometric entropy ½ln det Σ")):
                ax.set_xlabel("range (m)")
                ax.set_ylabel("viewing angle (deg; 0 = front)")
                ax.set_title(f"{name}: {title}")
                fig.colorbar(im, ax=ax)
        else:
            row[0].plot(r, conf[0], label="MLP")
            row[1].plot(r, ent[0], label="spline")
            row[0].set_title(f"{name}: confidence (range only)")
            row[1].set_title(f"{name}: geometric entropy ½ln det Σ")
            for ax in row[:2]:
                ax.set_xlabel("range (m)")
        if samples is not None:
            s = samples.of(name)
            row[0].scatter(
                s.range,
                np.degrees(s.angle) if m.angle_dependent else s.confidence,
                s=3,
                c="w" if m.angle_dependent else "0.4",
                alpha=0.4,
            )
        # standard deviation of each component against range at three angles
        for deg in (0, 45, 90) if m.angle_dependent else (0,):
            sd = np.sqrt(m.variances(r, np.full_like(r, math.radians(deg))))
            for k, comp in enumerate(m.components):
                row[2].plot(r, sd[:, k], label=f"{comp} @ {deg}°" if m.angle_dependent else comp)
        row[2].set_xlabel("range (m)")
        row[2].set_ylabel("predicted std (m)")
        row[2].set_title(f"{name}: geometric std per component")
        row[2].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
