"""The run report: metrics, the map, plots and ``report.md`` of a finished run.

An application observer of the kernel, registered through the ``amslam`` entry points like a
third party's (``report`` in pyproject.toml; ``plugins.disable: [report]`` leaves it out). It
implements two run-end hooks: ``amslam_run_metrics`` measures the run from its typed
:class:`amslam.types.RunSummary` (the kernel merges the figures into ``metrics.json`` and
``RunResult.metrics``), and ``amslam_run_end`` writes the map, the semantic map, the optimised
SLAM trajectory, the plots and ``report.md`` from the summary and the merged metrics.
"""

from __future__ import annotations

import bisect
import contextlib
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

import amslam
from amslam.apps.mapformats import (
    MapCloud,
    landmark_classes,
    probabilities_from_saved_map,
    write_map_ply,
)
from amslam.geometry import wrap_angle, yaw_of
from amslam.lib.class_colours import class_hex
from amslam.rundir import RunFiles, write_landmarks
from amslam.types import RunSummary, VoxelState, WorldSummary


def _floor_bands(world: WorldSummary) -> list[tuple[float, float]]:
    heights = list(world.floor_heights) or [float(world.bounds_lo[2])]
    tops = [*heights[1:], float(world.bounds_hi[2])]
    return list(zip(heights, tops, strict=True))


def explored_share(mapping, world: WorldSummary) -> tuple[float, list[float]]:
    """Share of the world's reachable free cells the global map knows, overall and per floor."""
    points = np.asarray(world.reachable_points, float).reshape(-1, 3)
    if len(points) == 0:
        return float("nan"), []
    known = mapping.states(points) != VoxelState.UNKNOWN
    per_floor = []
    for lo, hi in _floor_bands(world):
        inside = (points[:, 2] >= lo) & (points[:, 2] < hi)
        per_floor.append(float(known[inside].mean()) if inside.any() else float("nan"))
    return float(known.mean()), per_floor


def landmark_accuracy(landmarks: list, world: WorldSummary, gate: float = 1.0) -> dict[str, Any]:
    """How well the semantic map matches the world's objects.

    Landmarks and objects of the same class are paired one-to-one (Hungarian on distance, pairs
    within ``gate`` metres). ``duplicates`` are unpaired landmarks within ``gate`` of an object of
    their class (a second landmark for a mapped object); ``spurious`` are landmarks with no object
    of their class within ``gate``; ``off_by_more_than_0_5_m`` counts paired landmarks more than
    0.5 m from their object. ``by_class`` gives the same per class (issue #23's benchmark).

    ``common_offset_m`` is the mean of (landmark − object) over the paired landmarks (x, y, z):
    what the whole map is shifted by, a frame error the trajectory left (an early drift SLAM
    kept), which no landmark model removes; ``error_about_offset_m`` is the mean distance of each
    pair's difference from it: the landmarks' own error once the map's shift is taken out. The
    mean error is about their sum, so the two tell a trajectory's error from a landmark's.
    """
    from scipy.optimize import linear_sum_assignment

    ids = list(world.object_positions)
    if not landmarks or not ids:
        return {"matched": 0, "objects": len(ids), "duplicates": 0, "spurious": len(landmarks)}
    P = np.array([world.object_positions[i] for i in ids], dtype=float)
    pc = np.array([world.object_classes.get(i, "") for i in ids])
    Q = np.array([lm.position for lm in landmarks], dtype=float)
    qc = np.array([lm.class_name for lm in landmarks])
    d = np.linalg.norm(Q[:, None, :] - P[None, :, :], axis=2)
    d = np.where(qc[:, None] == pc[None, :], d, np.inf)
    r, c = linear_sum_assignment(np.where(d <= gate, d, 1e6))
    ok = d[r, c] <= gate
    err = d[r[ok], c[ok]]
    paired = set(r[ok].tolist())
    near = d.min(axis=1) <= gate
    duplicate = np.array([i not in paired and near[i] for i in range(len(Q))], dtype=bool)
    pair_class, pair_err = qc[r[ok]], err

    def block(objects: int, errors: np.ndarray, duplicates: int, spurious: int, landmarks: int) -> dict:
        return {
            "objects": objects,
            "landmarks": landmarks,
            "matched": len(errors),
            "mean_error_m": round(float(errors.mean()), 4) if len(errors) else None,
            "median_error_m": round(float(np.median(errors)), 4) if len(errors) else None,
            "off_by_more_than_0_5_m": int((errors > 0.5).sum()),
            "duplicates": duplicates,
            "spurious": spurious,
        }

    out = block(len(ids), err, int(duplicate.sum()), int((~near).sum()), len(Q))
    if ok.any():
        diff = Q[r[ok]] - P[c[ok]]
        offset = diff.mean(axis=0)
        out["common_offset_m"] = [round(float(v), 4) for v in offset]
        out["error_about_offset_m"] = round(float(np.linalg.norm(diff - offset, axis=1).mean()), 4)
    out["by_class"] = {
        cls: block(
            int((pc == cls).sum()),
            pair_err[pair_class == cls],
            int(duplicate[qc == cls].sum()),
            int((~near[qc == cls]).sum()),
            int((qc == cls).sum()),
        )
        for cls in sorted(set(pc.tolist()) | set(qc.tolist()))
    }
    return out


def in_amslam_classes(landmarks: list, world: WorldSummary) -> tuple[list, WorldSummary] | None:
    """The landmarks and the world's objects with their classes put through the world importer's
    packaged class map (``amslam world class-map``), or None when it renames no object's class.

    A mesh world made by others names its objects after its models (the shared house's
    ``kitchen_table``, ``reading_desk``, ``shoe_rack``); the ``sim`` detector reports those names,
    an image detector the classes it was trained on (``table``, ``shelf``), so by the world's own
    names an image detector's table never matches the house's tables. Here both sides speak
    amslam's classes: every table a ``table``, night stands and wardrobes ``cabinet``; objects and
    landmarks the map makes building structure (pictures) are left out; a class no rule names
    keeps its own (the procedural worlds' classes, ``car``, a house's ``carpet``).
    """
    from dataclasses import replace

    from amslam.apps.worlds.classmap import SKIP, STRUCTURE, load_class_map

    class_map = load_class_map()
    memo: dict[str, str] = {}

    def amslam_class(name: str) -> str:
        if name not in memo:
            hit = class_map.classify(name)
            memo[name] = hit[0] if hit else name
        return memo[name]

    if all(amslam_class(c) == c for c in set(world.object_classes.values())):
        return None
    dropped = (STRUCTURE, SKIP)
    classes = {i: amslam_class(c) for i, c in world.object_classes.items() if amslam_class(c) not in dropped}
    counts: dict[str, int] = {}
    for c in classes.values():
        counts[c] = counts.get(c, 0) + 1
    objects = replace(
        world,
        objects_by_class=counts,
        object_positions={i: q for i, q in world.object_positions.items() if i in classes},
        object_classes=classes,
    )
    mapped = [
        replace(lm, class_name=amslam_class(lm.class_name))
        for lm in landmarks
        if amslam_class(lm.class_name) not in dropped
    ]
    return mapped, objects


def _shape_ref(shape: dict) -> np.ndarray:
    return np.asarray(shape["center"] if shape["model"] == "cuboid" else shape["root"], float)


def _dims_abs_errors(est: dict, true: dict) -> np.ndarray:
    """|d_est − d_true| per dimension: a box's length, width, height; a cylinder's diameter.

    A box's length and width swap under a quarter turn: the estimate's dims are compared in the
    order its yaw agrees with (within 45°) the truth's.
    """
    if est["model"] == "cylinder":
        return np.array([abs(2.0 * float(est["radius"]) - 2.0 * float(true["radius"]))])
    de, dt = np.asarray(est["dims"], float), np.asarray(true["dims"], float)
    turn = abs(wrap_angle(2.0 * (float(est["yaw"]) - float(true["yaw"])))) > np.pi / 2  # off by ~90°
    return np.abs((de[[1, 0, 2]] if turn else de) - dt)


def _dims_error(est: dict, true: dict) -> float:
    """|d_est − d_true| averaged over all the dimensions (a box: l, w, h; a cylinder: its diameter)."""
    return float(np.mean(_dims_abs_errors(est, true)))


def _fig9_error(est: dict, true: dict) -> float:
    """Paper 2 Fig. 9's error of a vehicle: |Δlength| and |Δwidth| averaged (§V-B: "the accuracy
    of width and length estimates for target-class objects (i.e. vehicles)"; height is left out)."""
    return float(np.mean(_dims_abs_errors(est, true)[:2]))


def _stats(prefix: str, values: list[float]) -> dict[str, float]:
    if not values:
        return {}
    return {
        f"{prefix}_mean_m": round(float(np.mean(values)), 4),
        f"{prefix}_std_m": round(float(np.std(values)), 4),
    }


def object_accuracy(
    landmarks: list, world: WorldSummary, gate: float = 1.5, duplicate_radius: float = 3.0
) -> dict[str, Any]:
    """Shape landmarks against the world's true shapes (paper 2 Fig. 9), per class and overall.

    Per class of :attr:`WorldSummary.object_shapes`, landmarks with a shape of the same model are
    paired one-to-one with objects (Hungarian on the distance of the reference points: cuboid
    centre, cylinder root; pairs within ``gate`` metres). Per class:

    * ``mapped`` — the pairs; ``duplicates`` — unpaired landmarks within ``duplicate_radius`` of
      an object of the class (a second landmark of a mapped object, or one too far off its
      object to pair); ``spurious`` — the other unpaired landmarks;
    * ``fig9_error_mean_m`` / ``_std_m`` (cuboid classes only) — **paper 2 Fig. 9's metric**:
      per object the mean of |Δlength| and |Δwidth|, then mean and std over the mapped objects;
    * ``dims_error_mean_m`` / ``_std_m`` — the mean |Δd| over all dimensions (a box: length,
      width, height; a cylinder: its diameter, the only dimension it has);
    * ``position_error_mean_m`` / ``_median_m`` — distance of the paired reference points;
    * ``discovered`` — the objects paired the same way once the map's drift is taken out: one
      rigid 2-D transform (a turn about z and a shift, :func:`_drift_alignment`) fitted to the
      pairs of all classes and applied to every landmark. Paper 2 Fig. 9 counts the objects
      *discovered*; a survey's map 1 m off the world (its odometry's drift) pairs 90 % of the
      cars in place and 98 % once aligned (session 52's 15 overhead surveys), as trajectory
      error is read after alignment.

    ``overall`` pools the mapped objects of all classes for ``dims_error`` and ``position_error``,
    and only the cuboid (vehicle) classes for ``fig9_error`` (``fig9_objects``, ``fig9_mapped``):
    Fig. 9 evaluates the target class, vehicles; cylinders (poles, trunks) are not in it.
    """
    out: dict[str, Any] = {}
    all_dims: list[float] = []
    all_pos: list[float] = []
    all_fig9: list[float] = []
    fig9_objects = fig9_discovered = discovered = 0
    classes = sorted({world.object_classes.get(i, "") for i in world.object_shapes})
    align = _drift_alignment(landmarks, world, classes, gate)
    for cls in classes:
        ids = [i for i, s in world.object_shapes.items() if world.object_classes.get(i) == cls]
        row, errors = _class_accuracy(landmarks, world, ids, gate, duplicate_radius, align)
        discovered += row["discovered"]
        if row["model"] == "cuboid":
            fig9_objects += len(ids)
            fig9_discovered += row["discovered"]
        all_dims += errors["dims"]
        all_pos += errors["position"]
        all_fig9 += errors["fig9"]
        out[cls] = row
    out["overall"] = {
        "objects": len(world.object_shapes),
        "mapped": len(all_dims),
        "fig9_objects": fig9_objects,
        "fig9_mapped": len(all_fig9),
        "discovered": discovered,
        "fig9_discovered": fig9_discovered,
        **_stats("fig9_error", all_fig9),
        **_stats("dims_error", all_dims),
        **({"position_error_mean_m": round(float(np.mean(all_pos)), 4)} if all_pos else {}),
    }
    return out


def _shaped(landmarks: list, world: WorldSummary, ids: list) -> list:
    """The landmarks of the class of objects ``ids`` with a shape of their model."""
    model = world.object_shapes[ids[0]]["model"]
    cls = world.object_classes.get(ids[0])
    return [lm for lm in landmarks if lm.class_name == cls and lm.shape and lm.shape["model"] == model]


def _pairs(Q: np.ndarray, P: np.ndarray, gate: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One-to-one pairs of rows of Q (landmarks) and P (objects) within ``gate`` (Hungarian on
    distance): their indices and the distance matrix."""
    from scipy.optimize import linear_sum_assignment

    d = np.linalg.norm(Q[:, None, :] - P[None, :, :], axis=2)
    r, c = linear_sum_assignment(np.where(d <= gate, d, 1e6))
    ok = d[r, c] <= gate
    return r[ok], c[ok], d


def _drift_alignment(
    landmarks: list, world: WorldSummary, classes: list, gate: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """(R, t): the turn about z and shift (2-D) that best carry the shaped landmarks' reference
    points onto their objects' (least squares, Kabsch), from the pairs of every class within
    2 × ``gate`` and again within ``gate`` once aligned; None with fewer than 3 pairs."""
    shaped = []
    for cls in classes:
        ids = [i for i in world.object_shapes if world.object_classes.get(i) == cls]
        lms = _shaped(landmarks, world, ids)
        if lms:
            P = np.array([_shape_ref(world.object_shapes[i]) for i in ids])[:, :2]
            shaped.append((np.array([_shape_ref(lm.shape) for lm in lms])[:, :2], P))
    R, t = np.eye(2), np.zeros(2)
    for within in (2.0 * gate, gate):
        A, B = [], []
        for Q, P in shaped:
            r, c, _ = _pairs(Q @ R.T + t, P, within)
            A.append(Q[r])
            B.append(P[c])
        if not shaped or sum(len(a) for a in A) < 3:
            return None
        A, B = np.concatenate(A), np.concatenate(B)
        ma, mb = A.mean(0), B.mean(0)
        U, _, Vt = np.linalg.svd((A - ma).T @ (B - mb))
        D = np.diag([1.0, float(np.sign(np.linalg.det(Vt.T @ U.T)))])
        R = Vt.T @ D @ U.T
        t = mb - ma @ R.T
    return R, t


def _class_accuracy(
    landmarks: list,
    world: WorldSummary,
    ids: list,
    gate: float,
    duplicate_radius: float,
    align: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[dict[str, Any], dict[str, list[float]]]:
    """One class's row of :func:`object_accuracy` (its objects ``ids``), and the errors of its
    mapped objects (``dims``, ``position``, ``fig9``) for the overall figures; ``align``: the
    map's drift (:func:`_drift_alignment`) for ``discovered``."""
    model = world.object_shapes[ids[0]]["model"]
    lms = _shaped(landmarks, world, ids)
    row: dict[str, Any] = {
        "model": model,
        "objects": len(ids),
        "landmarks": len(lms),
        "mapped": 0,
        "discovered": 0,
    }
    errors: dict[str, list[float]] = {"dims": [], "position": [], "fig9": []}
    if not lms:
        return row, errors
    P = np.array([_shape_ref(world.object_shapes[i]) for i in ids])
    Q = np.array([_shape_ref(lm.shape) for lm in lms])
    r, c, d = _pairs(Q, P, gate)
    pairs = list(zip(r, c, strict=True))
    if align is None:
        row["discovered"] = len(pairs)
    else:
        Qa = Q.copy()
        Qa[:, :2] = Q[:, :2] @ align[0].T + align[1]
        row["discovered"] = len(_pairs(Qa, P, gate)[0])
    dims = [_dims_error(lms[a].shape, world.object_shapes[ids[b]]) for a, b in pairs]
    pos = d[r, c].tolist()
    paired = set(r.tolist())
    unpaired = [i for i in range(len(lms)) if i not in paired]
    row["mapped"] = len(pairs)
    row["duplicates"] = int(sum(d[i].min() <= duplicate_radius for i in unpaired))
    row["spurious"] = len(unpaired) - row["duplicates"]
    if model == "cuboid":
        errors["fig9"] = [_fig9_error(lms[a].shape, world.object_shapes[ids[b]]) for a, b in pairs]
        row.update(_stats("fig9_error", errors["fig9"]))
    row.update(_stats("dims_error", dims))
    if pos:
        row["position_error_mean_m"] = round(float(np.mean(pos)), 4)
        row["position_error_median_m"] = round(float(np.median(pos)), 4)
    errors["dims"], errors["position"] = dims, pos
    return row, errors


def compute_metrics(summary: RunSummary) -> dict[str, Any]:
    """The report's figures of a run: what it adds to the kernel's verdict, mission, seed and
    plugins in ``metrics.json``."""
    metrics: dict[str, Any] = {}
    if summary.duration_s is None:  # the platform never started
        return metrics
    metrics["sim_duration_s"] = round(summary.duration_s, 3)
    metrics["distance_m"] = round(summary.distance_m, 3)
    truth = summary.truth
    if len(truth) > 1:
        p = np.array([T[:3, 3] for _, T in truth])
        metrics["distance_truth_m"] = round(float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()), 3)
    status = summary.status
    if status is not None and status.closest_approach is not None:
        metrics["closest_approach"] = {
            "clearance_m": status.closest_approach,
            "robot_radius_m": summary.robot_radius,
            "to": status.closest_to,
            "position": list(status.closest_position or ()),
        }
    metrics.update(_ended_from_home(summary))
    metrics.update(_exploration_metrics(summary))
    metrics.update(_slam_metrics(summary))
    return metrics


def _ended_from_home(summary: RunSummary) -> dict[str, Any]:
    """Where the flight ended against its take-off spot: a robot that could not get home lands
    where it is, and the verdict alone would not say so."""
    truth = summary.truth
    if len(truth) > 1:
        ended = float(np.linalg.norm(truth[-1][1][:2, 3] - truth[0][1][:2, 3]))
    elif summary.home_world is not None and summary.final_vio is not None:
        here = (summary.final_T_world_odom @ summary.final_vio)[:3, 3]
        ended = float(np.linalg.norm(here[:2] - summary.home_world[:2]))
    else:
        return {}
    return {"ended_from_home_m": round(ended, 3)}


def _exploration_metrics(summary: RunSummary) -> dict[str, Any]:
    mapping, world = summary.mapping, summary.world
    if mapping is None:
        return {}
    out: dict[str, Any] = {
        "explored_volume_m3": round(mapping.explored_volume(), 3),
        "explored_series": [
            [round(t, 2), round(d, 2), round(v, 2)] for t, d, v in summary.samples["explored"]
        ],
    }
    if world is not None:
        share, per_floor = explored_share(mapping, world)
        out["reachable_free_volume_m3"] = round(world.reachable_free_volume, 3)
        out["floor_heights"] = [round(float(z), 3) for z in world.floor_heights]
        out["explored_percent"] = round(100 * share, 2)
        out["explored_percent_per_floor"] = [round(100 * s, 2) for s in per_floor]
    return out


def _trajectory_error(summary: RunSummary) -> dict[str, Any]:
    """Position error over the whole flight, not only at its end: VIO and the optimised SLAM key
    poses against the true trajectory (interpolated) at every key pose's stamp, RMS, mean and
    max. The end error of paper 1 Table I is one sample and swings by tenths of a metre between
    flights of the same code (an accepted loop closure just before landing, or not); this one is
    what a calibration compares. Without key poses (the odometry backend keeps none) VIO alone,
    at its own samples. Simulation only: it needs the true trajectory."""
    truth, vio = summary.truth, summary.vio
    if len(truth) < 2 or len(vio) < 2:
        return {}
    t_truth = np.array([t for t, _ in truth])
    p_truth = np.array([T[:3, 3] for _, T in truth])
    t_vio = np.array([t for t, _ in vio])
    p_vio = np.array([T[:3, 3] for _, T in vio])
    keyposes = sorted(summary.keyposes, key=lambda k: k.stamp) if summary.slam_optimises else []
    stamps = np.array([k.stamp for k in keyposes]) if keyposes else t_vio
    inside = (stamps >= max(t_truth[0], t_vio[0])) & (stamps <= min(t_truth[-1], t_vio[-1]))
    if not inside.any():
        return {}

    def at(t: np.ndarray, samples_t: np.ndarray, samples_p: np.ndarray) -> np.ndarray:
        return np.column_stack([np.interp(t, samples_t, samples_p[:, k]) for k in range(3)])

    true_p = at(stamps[inside], t_truth, p_truth)
    estimates = {"vio": at(stamps[inside], t_vio, p_vio)}
    if keyposes:
        estimates["slam"] = np.array([k.T_world_body[:3, 3] for k in keyposes])[inside]
    out: dict[str, Any] = {"at": "key poses" if keyposes else "VIO samples", "samples": int(inside.sum())}
    for name, p in estimates.items():
        err = np.linalg.norm(p - true_p, axis=1)
        out |= {
            f"{name}_rms_m": round(float(np.sqrt(np.mean(err**2))), 4),
            f"{name}_mean_m": round(float(err.mean()), 4),
            f"{name}_max_m": round(float(err.max()), 4),
        }
    return {"trajectory_error": out}


def _slam_metrics(summary: RunSummary) -> dict[str, Any]:
    out: dict[str, Any] = {}
    T_truth, T_vio = summary.final_truth, summary.final_vio
    if summary.final_T_world_odom is not None and T_truth is not None and T_vio is not None:
        T_slam = summary.final_T_world_odom @ T_vio
        out["final_error"] = {}
        for name, T in (("vio", T_vio), ("slam", T_slam)):
            offset = T[:3, 3] - T_truth[:3, 3]  # estimate minus truth, per axis (paper 1 Table I)
            yaw = wrap_angle(yaw_of(T) - yaw_of(T_truth))
            out["final_error"] |= {
                f"{name}_position_m": round(float(np.linalg.norm(offset)), 4),
                f"{name}_yaw_rad": round(abs(yaw), 5),
                f"{name}_offset_m": [round(float(v), 4) for v in offset],
                f"{name}_yaw_deg": round(float(np.degrees(yaw)), 3),
            }
    out.update(_trajectory_error(summary))
    if summary.landmarks is None:
        return out
    landmarks, world = list(summary.landmarks), summary.world
    by_class: dict[str, int] = {}
    for lm in landmarks:
        by_class[lm.class_name] = by_class.get(lm.class_name, 0) + 1
    out["landmarks"] = {"count": len(landmarks), "by_class": by_class}
    if world is not None:
        out["landmarks"]["objects_in_world"] = dict(world.objects_by_class)
        if world.object_positions:
            out["landmarks"]["accuracy"] = landmark_accuracy(landmarks, world)
            renamed = in_amslam_classes(landmarks, world)
            if renamed is not None:  # a mesh world's own class names (see in_amslam_classes)
                out["landmarks"]["accuracy_amslam_classes"] = landmark_accuracy(*renamed)
        if world.object_shapes and any(lm.shape for lm in landmarks):
            out["objects"] = object_accuracy(landmarks, world)
    out["keyposes"] = len(summary.keyposes)
    series = summary.samples["uncertainty"]
    if any(p or q for _, _, p, q in series):  # a backend without covariances reports zeros
        out["uncertainty"] = {
            "final_mean_pose_trace": series[-1][2],
            "final_mean_landmark_trace": series[-1][3],
            "series": [[round(t, 2), round(d, 2), p, q] for t, d, p, q in series],
            "pose_reduction_upon_slc_percent": reduction_upon_slc(
                series, [t for t, _, r in summary.slc_log if r.accepted]
            ),
        }
    out["slc"] = {
        "attempts": len(summary.slc_log),
        "accepted": sum(r.accepted for _, _, r in summary.slc_log),
        "events": [
            {
                "t": round(t, 2),
                "distance": round(d, 2),
                "accepted": r.accepted,
                "reason": r.reason,
                "matched": r.matched,
                "residual": r.residual,
                "yaw_correction": r.yaw_correction,
                "translation_correction": r.translation_correction,
            }
            for t, d, r in summary.slc_log
        ],
    }
    return out


def reduction_upon_slc(series: Sequence[tuple], slc_times: Sequence[float]) -> list[float]:
    """Per accepted SLC, the drop of the mean pose covariance trace across it, % (paper 1 Table II's
    "uncertainty reduction of avg. pose upon SLC"): from the last sample before the closure to
    the first at or after it. Samples come every ``exploration.uncertainty_period`` s; the
    panorama before a closure is flown in place, so the trace barely moves between them but for
    the closure. A closure with no sample on one side is left out."""
    out = []
    times = [float(row[0]) for row in series]
    for t in slc_times:
        i = bisect.bisect_left(times, t)
        if 0 < i < len(series) and series[i - 1][2] > 0:
            before, after = float(series[i - 1][2]), float(series[i][2])
            out.append(round(100.0 * (before - after) / before, 2))
    return out


def write_outputs(summary: RunSummary, metrics: dict[str, Any], rundir: RunFiles) -> None:
    """map.ply, map.npz, landmarks.json, slam.tum (optimised), plots and report.md (``metrics.json``
    is the kernel's: it is written before the run-end observers are called)."""
    mapping = summary.mapping
    if mapping is not None:
        with contextlib.suppress(NotImplementedError):  # a backend may not export
            mapping.save(rundir.path / "map.npz")  # the whole map, for a later run's prior_map
        write_map_ply(rundir.path / "map.ply", map_cloud(summary, rundir.path / "map.npz"))
    if summary.landmarks is not None:
        write_landmarks(rundir.path / "landmarks.json", summary.landmarks)
        kps = summary.keyposes
        if kps and summary.slam_optimises:
            # in time order: on a real vehicle a key pose made for a detection has its frame's
            # stamp, older than the latest odometry's (a SITL flight's slam.tum went back 0.17 s)
            kps = sorted(kps, key=lambda k: k.stamp)
            rundir.write_trajectory("slam", [k.stamp for k in kps], [k.T_world_body for k in kps])
    plots = []
    if mapping is not None:
        plots.append(plot_top_view(summary))
    if metrics.get("uncertainty", {}).get("series"):
        plots.append(plot_uncertainty(summary, metrics))
    write_report(summary, metrics, [p for p in plots if p])


def map_cloud(summary: RunSummary, saved_map: Path) -> MapCloud:
    """The occupied voxels of the final global map with their class (from the semantic map) and
    occupancy probability (from the log-odds ``saved_map`` holds, if the backend saved them)."""
    voxel = float(summary.mapping.voxel_size())
    points = np.asarray(summary.mapping.occupied_points(), float).reshape(-1, 3)
    classes, names = landmark_classes(points, summary.landmarks or (), voxel)
    probability = probabilities_from_saved_map(points, saved_map, voxel)
    return MapCloud(points, classes, probability, voxel, names)


#: the trajectories of ``top_view.png``: ground truth, VIO (odometry frame) and SLAM (key poses)
TRAJECTORY_STYLES = (("ground truth", "tab:green"), ("VIO", "tab:red"), ("SLAM", "tab:blue"))


def plot_top_view(summary: RunSummary) -> str | None:
    """``top_view.png``: occupied voxels per floor, trajectories and landmarks, seen from above."""
    import matplotlib.pyplot as plt

    fig = top_view_figure(summary)
    path = summary.run_dir / "top_view.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path.name


def _plan_extent(world: WorldSummary | None, clouds: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The (x, y) box every panel shows: the building's, so that each floor's panel has the same
    size whatever was flown there; without a world, what the map, trajectories and landmarks span."""
    if world is not None:
        lo, hi = np.asarray(world.bounds_lo, float)[:2], np.asarray(world.bounds_hi, float)[:2]
    else:
        xy = np.vstack([c[:, :2] for c in clouds if len(c)] or [np.zeros((1, 2))])
        lo, hi = xy.min(axis=0), xy.max(axis=0)
    margin = 0.03 * max(float(np.max(hi - lo)), 1.0)
    return lo - margin, hi + margin


def _in_band(points: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """The points with NaN where they leave the band ``[lo, hi)``: a line breaks there instead of
    jumping between floors."""
    out = np.array(points, float).reshape(-1, 3)
    out[~((out[:, 2] >= lo) & (out[:, 2] < hi))] = np.nan
    return out


def _draw_voxels(ax, points: np.ndarray, voxel: float) -> None:
    """Occupied voxels from above as filled grey cells of their true size (darker where a column
    holds more of them)."""
    if len(points) == 0:
        return
    cells = np.floor(points[:, :2] / voxel).astype(np.int64)
    first = cells.min(axis=0)
    shape = tuple(cells.max(axis=0) - first + 1)
    count = np.zeros(shape)
    np.add.at(count, tuple((cells - first).T), 1.0)
    shade = np.ma.masked_equal(count, 0.0).T  # rows are y for imshow
    lo = first * voxel
    hi = lo + np.array(shape) * voxel
    ax.imshow(
        shade,
        origin="lower",
        extent=(lo[0], hi[0], lo[1], hi[1]),
        cmap="Greys",
        vmin=-0.3 * count.max(),
        vmax=2.2 * count.max(),  # at most mid grey: the lines over it stay readable
        interpolation="nearest",
        zorder=0,
    )


def _draw_shape(ax, shape: dict, colour: str) -> None:
    """A landmark's fitted shape from above: a cuboid's footprint, a cylinder's circle."""
    import matplotlib.patches as mpatches

    from amslam.lib.shapes import cuboid_pose

    if shape["model"] == "cuboid":
        T = cuboid_pose(shape)
        half = np.asarray(shape["dims"], float)[:2] / 2
        corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half
        xy = corners @ T[:2, :2].T + T[:2, 3]
        ax.add_patch(mpatches.Polygon(xy, closed=True, fill=False, ec=colour, lw=1.0))
    elif shape["model"] == "cylinder":
        root = shape["root"]
        ax.add_patch(mpatches.Circle((root[0], root[1]), shape["radius"], fill=False, ec=colour, lw=1.0))


#: Width of one legend entry of the top view at font size 8 (marker and "occupied voxels"), and
#: the height of a row of entries, inches.
LEGEND_ENTRY_WIDTH = 1.55
LEGEND_ROW_HEIGHT = 0.22


def top_view_figure(summary: RunSummary):
    """The figure of ``top_view.png``: one panel per floor, all sized to the building; occupied
    voxels, the ground-truth, VIO and SLAM trajectories, and the landmarks coloured by class, with
    one legend under the panels (an entry per trajectory and per class)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    world = summary.world
    occupied = np.asarray(summary.mapping.occupied_points(), float).reshape(-1, 3)
    voxel = float(summary.mapping.voxel_size())
    bands = _floor_bands(world) if world is not None else [(-math.inf, math.inf)]
    trajectories = [
        summary.trajectory,
        np.array([T[:3, 3] for _, T in summary.vio]).reshape(-1, 3),
        np.array([k.T_world_body[:3, 3] for k in summary.keyposes]).reshape(-1, 3),
    ]
    landmarks = list(summary.landmarks or ())
    classes = sorted({lm.class_name for lm in landmarks})
    colour = {c: class_hex(c) for c in classes}  # as the simulator, rerun and the web viewer draw them
    positions = np.array([lm.position for lm in landmarks], float).reshape(-1, 3)
    lo, hi = _plan_extent(world, [occupied, *trajectories, positions])
    # every panel shows the building at one scale: its height fixed, its width following the plan
    panel_h = 5.0
    panel_w = float(np.clip(panel_h * (hi[0] - lo[0]) / (hi[1] - lo[1]), 3.0, 12.0))
    # the legend under the panels: as many columns as fit the figure's width (one row of nine
    # entries overflowed a one-panel figure at both edges), the figure as much taller as it has rows
    width = panel_w * len(bands) + 0.8
    entries = 1 + sum(len(t) > 0 for t in trajectories) + len(classes)
    columns = max(1, min(entries, int(width / LEGEND_ENTRY_WIDTH)))
    legend_h = 0.3 + LEGEND_ROW_HEIGHT * -(-entries // columns)
    fig, axes = plt.subplots(1, len(bands), figsize=(width, panel_h + 1.5 + legend_h), squeeze=False)
    for floor, (ax, (z0, z1)) in enumerate(zip(axes[0], bands, strict=True)):
        # Slice above the floor slab and below the ceiling, where walls and furniture are.
        band = (occupied[:, 2] > z0 + 0.3) & (occupied[:, 2] < min(z1, z0 + 2.2))
        _draw_voxels(ax, occupied[band], voxel)
        for points, (label, line_colour) in zip(trajectories, TRAJECTORY_STYLES, strict=True):
            if len(points):
                xyz = _in_band(points, z0, z1)
                ax.plot(xyz[:, 0], xyz[:, 1], "-", lw=0.9, color=line_colour, alpha=0.85, label=label)
        for lm in landmarks:
            if z0 <= lm.position[2] < z1:
                if lm.shape:
                    _draw_shape(ax, lm.shape, colour[lm.class_name])
                ax.plot(
                    lm.position[0],
                    lm.position[1],
                    "o",
                    ms=4.5,
                    mfc=colour[lm.class_name],
                    mec="white",
                    mew=0.5,
                )
        ax.set_title("" if math.isinf(z0) else f"floor {floor}: z ∈ [{z0:.1f}, {z1:.1f}) m", fontsize=10)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    counts = {c: sum(lm.class_name == c for lm in landmarks) for c in classes}
    handles = [Line2D([], [], ls="", marker="s", ms=4, mfc="0.6", mec="0.6", label="occupied voxels")]
    handles += [
        Line2D([], [], color=c, lw=1.5, label=label)
        for (label, c), points in zip(TRAJECTORY_STYLES, trajectories, strict=True)
        if len(points)
    ]
    handles += [
        Line2D([], [], ls="", marker="o", ms=6, mfc=colour[c], mec="white", label=f"{c} ×{counts[c]}")
        for c in classes
    ]
    fig.legend(handles=handles, loc="lower center", ncol=columns, fontsize=8, frameon=False)
    fig.suptitle(f"{summary.mission.name}: map, trajectories and landmarks (top view)")
    fig.tight_layout(rect=(0, legend_h / fig.get_figheight(), 1, 1))
    return fig


def plot_uncertainty(summary: RunSummary, metrics: dict[str, Any]) -> str | None:
    """``uncertainty.png``: mean pose and landmark covariance traces against time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series = np.array(metrics["uncertainty"]["series"], dtype=float)
    fig, axes = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
    axes[0].plot(series[:, 0], series[:, 2], color="tab:purple")
    axes[0].set_ylabel("mean pose tr(Σ)")
    axes[1].plot(series[:, 0], series[:, 3], color="tab:orange")
    axes[1].set_ylabel("mean landmark tr(Σ)")
    axes[1].set_xlabel("time (s)")
    fig.suptitle(f"{summary.mission.name}: uncertainty over time")
    fig.tight_layout()
    path = summary.run_dir / "uncertainty.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path.name


def write_report(summary: RunSummary, metrics: dict[str, Any], plots: list[str]) -> None:
    """``report.md`` tying the run's files together."""
    lines = [
        f"# Run report: {metrics.get('mission')}",
        "",
        f"**Verdict: {metrics['verdict']}**",
        "",
        "| figure | value |",
        "|---|---|",
        *_figure_rows(metrics),
    ]
    lines += ["", "## Plots", ""]
    lines += [f"![{p}]({p})" for p in plots]
    lines += files_section(summary.run_dir)
    (summary.run_dir / "report.md").write_text("\n".join(lines))


#: what each file of a run folder holds: (its files, the line about them); ``report.md`` ends with
#: the lines whose files the run wrote
FILES = [
    (("mission.yaml",), "- [mission.yaml](mission.yaml) — the mission as flown, every default filled in"),
    (("metrics.json",), "- [metrics.json](metrics.json) — the figures above, machine-readable"),
    (("events.jsonl",), "- [events.jsonl](events.jsonl) — replans, loop closures, errors, in time order"),
    (("tree.jsonl",), "- [tree.jsonl](tree.jsonl) — behaviour-tree changes per tick"),
    (
        ("ground_truth.tum", "vio.tum", "slam.tum"),
        "- {links} — trajectories (TUM format, e.g. `evo_ape tum ground_truth.tum slam.tum`)",
    ),
    (("landmarks.json",), "- [landmarks.json](landmarks.json) — the semantic map"),
    (
        ("map.ply",),
        "- [map.ply](map.ply) — occupied voxels of the global map (binary PLY: class and occupancy"
        " probability per voxel, the voxel size in its header; `amslam map RUN --bt FILE` makes an"
        " OctoMap of it)",
    ),
    (("map.npz",), "- [map.npz](map.npz) — the whole map with its log-odds, a later mission's `prior_map`"),
]


def files_section(run_dir: Path) -> list[str]:
    """The ``## Files`` section: a line per file (or group) the run folder holds, none for files a
    run that failed early never wrote (its report linked to them)."""
    lines = ["", "## Files", ""]
    for names, text in FILES:
        present = [n for n in names if (run_dir / n).is_file()]
        if present:
            lines.append(text.format(links=", ".join(f"[{n}]({n})" for n in present)))
    return [*lines, ""]


def _figure_rows(m: dict[str, Any]) -> list[str]:
    """The rows of ``report.md``'s figure table, for the figures ``metrics`` has."""
    lines: list[str] = []

    def row(label: str, value: Any) -> None:
        if value is not None:
            lines.append(f"| {label} | {value} |")

    row("seed", m.get("seed"))
    row("exploration ended", m.get("exploration_end"))
    row("way home", m.get("way_home"))
    row("backends", ", ".join(f"{k}={v}" for k, v in m.get("plugins", {}).items()))
    row("duration (s)", m.get("sim_duration_s"))
    row("distance travelled (m)", m.get("distance_m"))
    row("ended this far from the take-off spot, horizontally (m)", m.get("ended_from_home_m"))
    row("explored volume (m³)", m.get("explored_volume_m3"))
    row("reachable free volume (m³)", m.get("reachable_free_volume_m3"))
    row("explored (% of reachable free volume)", m.get("explored_percent"))
    if m.get("explored_percent_per_floor"):
        row("explored per floor (%)", ", ".join(str(v) for v in m["explored_percent_per_floor"]))
    if close := m.get("closest_approach"):
        row(
            f"closest approach to any surface (m; robot radius {close['robot_radius_m']})",
            f"{close['clearance_m']} to {close['to']} at {close['position']}",
        )
    err = m.get("final_error")
    if err:
        row("final position error VIO / SLAM (m)", f"{err['vio_position_m']} / {err['slam_position_m']}")
        row("final yaw error VIO / SLAM (rad)", f"{err['vio_yaw_rad']} / {err['slam_yaw_rad']}")
    if track := m.get("trajectory_error"):
        row(
            f"position error over the flight, RMS at {track['samples']} {track['at']} (m)",
            " / ".join(
                f"{name} {track[f'{name}_rms_m']}" for name in ("vio", "slam") if f"{name}_rms_m" in track
            ),
        )
    lm = m.get("landmarks")
    if lm:
        row("landmarks (by class)", f"{lm['count']} {lm['by_class']}")
        if "objects_in_world" in lm:
            row("objects in the world", lm["objects_in_world"])
        acc = lm.get("accuracy")
        if acc and acc.get("matched"):
            row(
                "landmarks vs objects",
                f"{acc['matched']} of {acc['objects']} objects mapped, mean error {acc['mean_error_m']} m, "
                f"{acc['off_by_more_than_0_5_m']} off by > 0.5 m, {acc['duplicates']} duplicates, "
                f"{acc['spurious']} spurious",
            )
    if m.get("slc"):
        row(
            "semantic loop closures (accepted / attempts)", f"{m['slc']['accepted']} / {m['slc']['attempts']}"
        )
    if (interval := m.get("control_tick_interval_ms")) and "control_tick_overruns" in m:
        # a real-time run (the realtime observer's figures): how often the control loop was late
        load = m.get("host_load") or {}
        late_after = m.get("control_tick_overruns_by_behaviour") or {}
        row(
            f"control ticks late (interval > 1.25 × {m.get('control_period_ms')} ms)",
            f"{m['control_tick_overruns']} of {m.get('control_ticks')}"
            f" ({m.get('control_tick_overrun_percent')} %);"
            f" interval median {interval['median']}, p95 {interval['p95']}, max {interval['max']} ms;"
            f" host load {_load_text(load)}"
            + "".join(f"; {n} after {name}" for name, n in late_after.items()),
        )
    if pipeline := m.get("pipeline"):
        row(
            "camera frames (received / in the global map / skipped by the busy mapper / detected)",
            " / ".join(str(pipeline[k]) for k in ("frames", "mapped", "skipped_by_mapper", "detected")),
        )
        for key, figures in pipeline.get("latency_ms", {}).items():
            row(
                f"latency {key.replace('_', ' ')} (ms)",
                f"median {figures['median']}, p95 {figures['p95']}, max {figures['max']}"
                f" ({figures['n']} samples)",
            )
    return lines


def _load_text(load: dict[str, Any]) -> str:
    """``host_load`` as "4.1 → 3.2 (1-min average) on 2 CPUs" (what made a run late is often not amslam)."""
    one = [v[0] if isinstance(v, list | tuple) and v else v for v in (load.get("start"), load.get("end"))]
    text = " → ".join(f"{v:.1f}" for v in one if isinstance(v, int | float))
    return f"{text or '?'} (1-min average) on {load.get('cpus', '?')} CPUs"


@amslam.hookimpl
def amslam_run_metrics(summary: RunSummary) -> dict[str, Any]:
    return compute_metrics(summary)


@amslam.hookimpl
def amslam_run_end(run_dir: Path, metrics: dict[str, Any], summary: RunSummary) -> None:
    write_outputs(summary, metrics, RunFiles(run_dir))
