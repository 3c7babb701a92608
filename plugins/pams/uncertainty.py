"""Fitting the empirical uncertainty models against range and viewing angle (paper 2 §IV-C).

The models themselves (evaluation, persistence, the packaged defaults) are the library's
(:mod:`amslam.lib.uncertainty`, re-exported here): the SLAM backend reads them too.

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

import math
import warnings
from pathlib import Path

import numpy as np

from amslam.lib.uncertainty import (
    COMPONENTS,
    DEFAULT_MODELS_PATH,
    FORMAT,
    POSITION_COMPONENTS,
    ClassModel,
    LogVarianceSpline,
    Mlp,
    UncertaintyModels,
)

__all__ = [
    "COMPONENTS",
    "DEFAULT_MODELS_PATH",
    "FORMAT",
    "POSITION_COMPONENTS",
    "ClassModel",
    "LogVarianceSpline",
    "Mlp",
    "UncertaintyModels",
    "cell_variances",
    "fit_log_variance",
    "fit_models",
    "plot_models",
]


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
        samples: :class:`amslam.apps.characterisation.Samples` (or anything with its fields).
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
