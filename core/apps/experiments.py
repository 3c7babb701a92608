"""Experiments: one mission flown several ways over several seeds, summarised in tables and plots.

* ``slc-ablation`` — one or more missions with semantic loop closure on and off (paper 1 Tables
  I, II and Fig. 7): end position and yaw error of VIO vs SLAM, pose and landmark uncertainty,
  mean ± std per world and over all.
* ``planners`` — one or more missions with each exploration planner (COP, TSP, greedy):
  explored volume against distance travelled and time, mean ± std per world and over all.
* ``calibrate`` — one parameter's value chosen on training seeds and judged on held-out seeds
  (:mod:`amslam.apps.calibration`).

Every run is an ordinary run folder under ``<out>/<experiment>-<mission>-<timestamp>/runs``; the
experiment folder adds ``results.json``, ``table.md`` and PNG plots.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

import amslam
from amslam.apps import calibration
from amslam.apps.flights import (
    SERIAL,
    Flight,
    FlightRunner,
    code_note,
    experiment_folder,
    flight_arguments,
    fly_all,
)
from amslam.apps.tables import mean_std
from amslam.cli import Experiment
from amslam.registry import Registry


def _pct_reduction(before: float, after: float) -> float:
    return 100.0 * (before - after) / before if before else float("nan")


def _mean(values: Any) -> float | None:
    """The mean of the finite ones among ``values`` (None and NaN are runs that did not measure
    it); None, shown as "—", when there are none: every run failed, say."""
    finite = [float(v) for v in values if v is not None and np.isfinite(v)]
    return float(np.mean(finite)) if finite else None


def _fmt(x: Any, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return "—"
    return f"{x:.{digits}f}" if isinstance(x, float) else str(x)


# -- SLC ablation ----------------------------------------------------------------------------


def slc_ablation(
    specs: list[str],
    registry: Registry,
    seeds: list[int],
    out: Path,
    overrides: list[str] = (),
    log: Callable[[str], None] = print,
    runner: FlightRunner = SERIAL,
    resume: str | None = None,
) -> Path:
    """Fly every mission with SLC on and off for each seed; write tables and the Fig. 7 plot."""
    folder = experiment_folder(out, "slc-ablation", specs[0] if len(specs) == 1 else "worlds", resume)
    cases = [(spec, seed, slc) for spec in specs for seed in seeds for slc in ("on", "off")]
    flights = [
        Flight(spec, (*overrides, f"seed={seed}", f"exploration.slc={'true' if slc == 'on' else 'false'}"))
        for spec, seed, slc in cases
    ]
    flown = fly_all(flights, folder, runner, log, registry)
    rows = []
    for spec in specs:
        for seed in seeds:
            pair = {
                slc: rec for (w, s_, slc), rec in zip(cases, flown, strict=True) if (w, s_) == (spec, seed)
            }
            rows.append({"world": Path(spec).stem, "seed": seed, **pair})
    (folder / "results.json").write_text(json.dumps(rows, indent=2, default=str))
    (folder / "table.md").write_text(slc_tables(rows) + code_note(flown))
    plot_fig7(rows, folder / "uncertainty_slc_on_off.png")
    plot_trajectories(rows, folder / "trajectories.png")
    return folder


def plot_trajectories(rows: list[dict], path: Path) -> None:
    """Paper 1 Fig. 5 / Fig. 8 style: per world, the first seed with both flights' folders, each
    flight's true trajectory against its VIO and SLAM estimates, from above (X-Y) and from the
    side (X-Z): the SLC-on flight on the left, the SLC-off flight on the right (a flight of its
    own: it goes elsewhere once the first loop closure is not flown). Nothing is drawn when no
    pair of flights left its trajectories."""
    from amslam.errors import RunFileError
    from amslam.rundir import read_tum

    def tracks(folder: str | None) -> dict[str, np.ndarray] | None:
        if not folder:
            return None
        try:
            return {
                label: read_tum(Path(folder) / f"{name}.tum").poses[:, :3]
                for label, name in (("truth", "ground_truth"), ("VIO", "vio"), ("SLAM", "slam"))
            }
        except RunFileError:
            return None

    chosen: dict[str, tuple[int, dict, dict]] = {}
    for row in rows:
        world = row.get("world", "")
        if world in chosen:
            continue
        on, off = tracks(row["on"].get("run_dir")), tracks(row["off"].get("run_dir"))
        if on is not None and off is not None:
            chosen[world] = (row["seed"], on, off)
    if not chosen:
        return
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    styles = {"truth": ("k", "-"), "VIO": ("tab:red", "--"), "SLAM": ("tab:blue", "-")}
    fig, axes = plt.subplots(len(chosen), 4, figsize=(22, 4.2 * len(chosen)), squeeze=False)
    for (world, (seed, on, off)), panels in zip(chosen.items(), axes, strict=True):
        for (top, side), t, slc in ((panels[:2], on, "on"), (panels[2:], off, "off")):
            for label, xyz in t.items():
                colour, line = styles[label]
                top.plot(xyz[:, 0], xyz[:, 1], line, color=colour, lw=1, label=label)
                side.plot(xyz[:, 0], xyz[:, 2], line, color=colour, lw=1, label=label)
            top.set_title(f"{world}, seed {seed}, SLC {slc}: from above")
            side.set_title(f"{world}, seed {seed}, SLC {slc}: from the side")
            top.set_aspect("equal", adjustable="datalim")
            top.set_xlabel("x (m)")
            top.set_ylabel("y (m)")
            side.set_xlabel("x (m)")
            side.set_ylabel("z (m)")
            top.legend(fontsize=7)
    fig.suptitle("Trajectories: truth, VIO and SLAM, with semantic loop closure (left) and without (right)")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _xyz(offset: Any) -> str:
    """A per-axis error ``(x, y, z)`` in metres, or "—" for runs that did not record it."""
    if not offset:
        return "—"
    return "(" + ", ".join(f"{v:+.2f}" for v in offset) + ")"


def _yaw_deg(err: dict[str, Any], name: str) -> float | None:
    """The signed final yaw error in degrees; runs from before it was recorded give |yaw|."""
    if err.get(f"{name}_yaw_deg") is not None:
        return float(err[f"{name}_yaw_deg"])
    rad = err.get(f"{name}_yaw_rad")
    return None if rad is None else float(np.degrees(rad))


def _ablation_figures(row: dict) -> dict[str, Any]:
    """One seed's figures: SLAM (SLC on) against VIO and against SLAM with SLC off."""
    on, off = row["on"]["metrics"], row["off"]["metrics"]
    err, err_off = on.get("final_error", {}), off.get("final_error", {})
    vio_p, slam_p, off_p = (
        err.get("vio_position_m"),
        err.get("slam_position_m"),
        err_off.get("slam_position_m"),
    )
    vio_y, slam_y, off_y = _yaw_deg(err, "vio"), _yaw_deg(err, "slam"), _yaw_deg(err_off, "slam")
    u_on, u_off = on.get("uncertainty", {}), off.get("uncertainty", {})
    p_on, p_off = u_on.get("final_mean_pose_trace"), u_off.get("final_mean_pose_trace")
    l_on, l_off = u_on.get("final_mean_landmark_trace"), u_off.get("final_mean_landmark_trace")
    length = on.get("distance_m")
    nan = float("nan")
    return {
        "vio_p": vio_p,
        "slam_p": slam_p,
        "off_p": off_p,
        "vio_y": vio_y,
        "slam_y": slam_y,
        "off_y": off_y,
        "length": length,
        "pos_vs_vio": _pct_reduction(vio_p, slam_p) if vio_p is not None and slam_p is not None else nan,
        "yaw_vs_vio": _pct_reduction(abs(vio_y), abs(slam_y))
        if vio_y is not None and slam_y is not None
        else nan,
        "pos_vs_off": _pct_reduction(off_p, slam_p) if off_p is not None and slam_p is not None else nan,
        "yaw_vs_off": _pct_reduction(abs(off_y), abs(slam_y))
        if off_y is not None and slam_y is not None
        else nan,
        "drift": 100.0 * vio_p / length if vio_p is not None and length else nan,
        "pose_unc": _pct_reduction(p_off, p_on) if p_on is not None and p_off else nan,
        "lm_unc": _pct_reduction(l_off, l_on) if l_on is not None and l_off else nan,
        "p_on": p_on,
        "p_off": p_off,
        "l_on": l_on,
        "l_off": l_off,
        "upon": list(u_on.get("pose_reduction_upon_slc_percent") or []),
        "accepted": on.get("slc", {}).get("accepted", 0),
        "attempts": on.get("slc", {}).get("attempts"),
        "completed": [row[k]["metrics"].get("verdict") == "completed" for k in ("on", "off")],
        "slam_below_vio": slam_p is not None and vio_p is not None and slam_p < vio_p,
    }


def slc_tables(rows: list[dict]) -> str:
    """Markdown tables like paper 1 Tables I and II from the runs of an ablation.

    Table I (SLC on): the end position error of VIO and SLAM with its X/Y/Z components (estimate
    minus truth), VIO's drift as a share of the trajectory, the yaw errors in degrees (signed) and
    the trajectory length. Table II: the mean pose covariance trace's drop across each accepted
    SLC ("upon SLC"), and the final mean pose and landmark traces with SLC against without. Then a
    summary per world and over all flights, mean ± std over seeds: the reductions against VIO
    and against the same seed flown with SLC off.
    """
    figures = [_ablation_figures(row) for row in rows]
    lines = [*_table_one(rows, figures), "", *_table_two(rows, figures), "", *_summary(rows, figures)]
    return "\n".join([*lines, ""])


def _table_one(rows: list[dict], figures: list[dict]) -> list[str]:
    """Paper 1 Table I: the end-of-mission errors with SLC on, one line per flight and the mean."""
    lines = [
        "## End-of-mission errors with SLC on (like paper 1 Table I)",
        "",
        "| world | seed | traj. len. (m) | SLC accepted | VIO pos. err (m) (X, Y, Z) | "
        "SLAM pos. err (m) (X, Y, Z) | reduction | VIO drift (% of traj.) | VIO yaw err (°) | "
        "SLAM yaw err (°) | reduction |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row, f in zip(rows, figures, strict=True):
        err = row["on"]["metrics"].get("final_error", {})
        lines.append(
            f"| {row.get('world', '')} | {row['seed']} | {_fmt(f['length'], 1)} | {f['accepted']} | "
            f"{_fmt(f['vio_p'], 2)} {_xyz(err.get('vio_offset_m'))} | "
            f"{_fmt(f['slam_p'], 2)} {_xyz(err.get('slam_offset_m'))} | "
            f"{_fmt(f['pos_vs_vio'], 1)} % | {_fmt(f['drift'], 2)} % | {_fmt(f['vio_y'], 2)} | "
            f"{_fmt(f['slam_y'], 2)} | {_fmt(f['yaw_vs_vio'], 1)} % |"
        )
    lines.append(
        f"| **mean** | | | | | | **{_fmt(_mean(f['pos_vs_vio'] for f in figures), 1)} %** | "
        f"{_fmt(_mean(f['drift'] for f in figures), 2)} % | | | "
        f"**{_fmt(_mean(f['yaw_vs_vio'] for f in figures), 1)} %** |"
    )
    return lines


def _table_two(rows: list[dict], figures: list[dict]) -> list[str]:
    """Paper 1 Table II: the uncertainty's drop upon each SLC and its final value, SLC on vs off."""
    lines = [
        "## Uncertainty reduction, upon SLC and SLC on vs off (like paper 1 Table II / Fig. 7)",
        "",
        "| world | seed | avg. pose upon SLC | pose tr(Σ) on | pose tr(Σ) off | reduction | "
        "landmark tr(Σ) on | landmark tr(Σ) off | reduction | traj. len. on (m) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row, f in zip(rows, figures, strict=True):
        lines.append(
            f"| {row.get('world', '')} | {row['seed']} | "
            f"{'; '.join(f'{x:.1f} %' for x in f['upon']) or '—'} | "
            f"{_fmt(f['p_on'], 4)} | {_fmt(f['p_off'], 4)} | {_fmt(f['pose_unc'], 1)} % | "
            f"{_fmt(f['l_on'], 4)} | {_fmt(f['l_off'], 4)} | {_fmt(f['lm_unc'], 1)} % | "
            f"{_fmt(f['length'], 1)} |"
        )
    lines.append(
        f"| **mean** | | {_fmt(_mean(x for f in figures for x in f['upon']), 1)} % | | | "
        f"**{_fmt(_mean(f['pose_unc'] for f in figures), 1)} %** | | | "
        f"**{_fmt(_mean(f['lm_unc'] for f in figures), 1)} %** | |"
    )
    return lines


def _summary(rows: list[dict], figures: list[dict]) -> list[str]:
    """Mean ± std over seeds per world (and over all flights when there are several worlds)."""
    lines = [
        "## Summary, mean ± std over seeds",
        "",
        "Reductions of SLAM with SLC on against VIO (paper 1 Table I) and against SLAM with SLC off "
        "(the same seed); uncertainty: final mean traces, SLC on against off.",
        "",
        "| world | seeds | completed (on / off) | SLAM < VIO | SLC accepted / attempted | "
        "pos. vs VIO | pos. vs SLC off | yaw vs VIO | yaw vs SLC off | pose tr(Σ) | landmark tr(Σ) | "
        "upon SLC |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    worlds = list(dict.fromkeys(row.get("world", "") for row in rows))
    groups = [
        (w, [f for row, f in zip(rows, figures, strict=True) if row.get("world", "") == w]) for w in worlds
    ]
    if len(worlds) > 1:
        groups.append(("**all**", figures))
    for name, fs in groups:
        attempts = [f["attempts"] for f in fs if f["attempts"] is not None]
        done_on, done_off = (sum(f["completed"][k] for f in fs) for k in (0, 1))
        lines.append(
            f"| {name} | {len(fs)} | {done_on} / {done_off} | "
            f"{sum(f['slam_below_vio'] for f in fs)} of {len(fs)} | "
            f"{sum(f['accepted'] for f in fs)} / {sum(attempts) if attempts else '—'} | "
            + " | ".join(
                mean_std((f[key] for f in fs), unit=" %")
                for key in ("pos_vs_vio", "pos_vs_off", "yaw_vs_vio", "yaw_vs_off", "pose_unc", "lm_unc")
            )
            + f" | {mean_std((x for f in fs for x in f['upon']), unit=' %')} |"
        )
    lines += [
        "",
        "Of the summed errors, 1 − Σ after / Σ before over the flights: a flight whose VIO barely drifted"
        " (a yaw error of 0.1°) weighs by its error, where its own percentage swings by hundreds.",
        "",
        "| world | flights | pos. vs VIO | pos. vs SLC off | yaw vs VIO | yaw vs SLC off | pose tr(Σ) | "
        "landmark tr(Σ) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    pairs = (("vio_p", "slam_p"), ("off_p", "slam_p"), ("vio_y", "slam_y"), ("off_y", "slam_y"))
    pairs += (("p_off", "p_on"), ("l_off", "l_on"))
    for name, fs in groups:
        pooled = [_pooled_reduction(fs, before, after) for before, after in pairs]
        cells = [f"{x:.1f} %" if np.isfinite(x) else "—" for x in pooled]
        lines.append(f"| {name} | {len(fs)} | " + " | ".join(cells) + " |")
    return lines


def _pooled_reduction(figures: list[dict], before: str, after: str) -> float:
    """1 − Σ|after| / Σ|before| (%) over the flights that have both figures; nan without any."""
    both = [
        (abs(f[before]), abs(f[after])) for f in figures if f[before] is not None and f[after] is not None
    ]
    total = sum(b for b, _ in both)
    return _pct_reduction(total, sum(a for _, a in both)) if both and total > 0 else float("nan")


def plot_fig7(rows: list[dict], path: Path) -> None:
    """Mean pose and landmark covariance trace against distance, SLC on and off (paper 1 Fig. 7),
    one row of two panels per world; a seed keeps its colour, SLC on solid, off dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    drawn = [
        (row, key, style, series)
        for row in rows
        for key, style in (("on", "-"), ("off", "--"))
        if (series := row[key]["metrics"].get("uncertainty", {}).get("series"))
    ]
    if not drawn:  # no run measured its uncertainty (every run failed, say): no empty plot
        return
    worlds = list(dict.fromkeys(row.get("world", "") for row, *_ in drawn))
    fig, axes = plt.subplots(len(worlds), 2, figsize=(11, 3.6 * len(worlds)), squeeze=False)
    seeds = list(dict.fromkeys(row["seed"] for row, *_ in drawn))
    for row, key, style, series in drawn:
        s = np.array(series, dtype=float)
        pose_ax, landmark_ax = axes[worlds.index(row.get("world", ""))]
        colour = f"C{seeds.index(row['seed']) % 10}"
        label = f"seed {row['seed']}, SLC {key}"
        pose_ax.plot(s[:, 1], s[:, 2], style, color=colour, label=label)
        landmark_ax.plot(s[:, 1], s[:, 3], style, color=colour, label=label)
        for ev in row[key]["metrics"].get("slc", {}).get("events", []):
            if ev["accepted"]:
                pose_ax.axvline(ev["distance"], color="0.8", lw=0.6, zorder=0)
    for world, (pose_ax, landmark_ax) in zip(worlds, axes, strict=True):
        name = f"{world}: " if world else ""
        pose_ax.set_title(f"{name}mean pose uncertainty")
        landmark_ax.set_title(f"{name}mean landmark uncertainty")
        for ax in (pose_ax, landmark_ax):
            ax.set_xlabel("distance travelled (m)")
            ax.set_ylabel("tr(Σ)")
        landmark_ax.legend(fontsize=6, ncol=2)
    fig.suptitle("Uncertainty with and without semantic loop closure (grey: accepted SLC)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# -- planner comparison ----------------------------------------------------------------------


def planner_comparison(
    specs: list[str],
    registry: Registry,
    seeds: list[int],
    out: Path,
    planners: tuple[str, ...] = ("cop", "tsp", "greedy"),
    overrides: list[str] = (),
    log: Callable[[str], None] = print,
    runner: FlightRunner = SERIAL,
    resume: str | None = None,
) -> Path:
    """Fly every mission with each planner for each seed; tabulate and plot exploration progress."""
    folder = experiment_folder(out, "planners", specs[0] if len(specs) == 1 else "worlds", resume)
    cases = [(spec, seed, planner) for spec in specs for seed in seeds for planner in planners]
    flights = [
        Flight(spec, (*overrides, f"seed={seed}", f"planner.plugin={planner}"))
        for spec, seed, planner in cases
    ]
    flown = fly_all(flights, folder, runner, log, registry)
    rows = [
        {"seed": seed, "planner": planner, "world": Path(spec).stem, **rec}
        for (spec, seed, planner), rec in zip(cases, flown, strict=True)
    ]
    (folder / "results.json").write_text(json.dumps(rows, indent=2, default=str))
    (folder / "table.md").write_text(planner_table(rows) + code_note(flown))
    plot_exploration(rows, folder / "explored_vs_distance.png")
    return folder


def progress_to(rows: list[dict], share: float = 0.9) -> list[tuple[float | None, float | None]]:
    """Per run, the distance and time at which it had mapped ``share`` of the most volume any run of
    the same world and seed mapped: how fast a planner explores, not counting the flight home."""
    best: dict[Any, float] = {}
    for row in rows:
        key = (row.get("world"), row["seed"])
        best[key] = max(best.get(key, 0.0), row["metrics"].get("explored_volume_m3") or 0.0)
    out = []
    for row in rows:
        target = share * best[(row.get("world"), row["seed"])]
        series = np.array(row["metrics"].get("explored_series") or np.zeros((0, 3)), dtype=float)
        hit = np.flatnonzero(series[:, 2] >= target) if len(series) and target > 0 else []
        out.append((float(series[hit[0], 1]), float(series[hit[0], 0])) if len(hit) else (None, None))
    return out


def planner_table(rows: list[dict]) -> str:
    lines = [
        "| planner | world | seed | verdict | explored (%) | distance (m) | time (s) | m³ per m "
        "| distance to 90 % (m) | time to 90 % (s) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    to90 = progress_to(rows)
    for row, (d90, t90) in zip(rows, to90, strict=True):
        m = row["metrics"]
        vol, dist = m.get("explored_volume_m3"), m.get("distance_m")
        lines.append(
            f"| {row['planner']} | {row.get('world', '')} | {row['seed']} | {m.get('verdict')} | "
            f"{_fmt(m.get('explored_percent'), 1)} | {_fmt(dist, 1)} | {_fmt(m.get('sim_duration_s'), 1)} | "
            f"{_fmt(vol / dist if vol and dist else None, 2)} | {_fmt(d90, 1)} | {_fmt(t90, 1)} |"
        )
    lines += [
        "",
        "| planner | runs | mean explored (%) | mean distance (m) | mean time (s) "
        "| mean distance to 90 % (m) | mean time to 90 % (s) |",
        "|---|---|---|---|---|---|---|",
    ]
    for planner in dict.fromkeys(r["planner"] for r in rows):
        ms = [r["metrics"] for r in rows if r["planner"] == planner]
        p90 = [x for r, x in zip(rows, to90, strict=True) if r["planner"] == planner]

        def mean(key: str, ms=ms) -> float | None:
            return _mean(m.get(key) for m in ms)

        lines.append(
            f"| {planner} | {len(ms)} | {_fmt(mean('explored_percent'), 1)} | "
            f"{_fmt(mean('distance_m'), 1)} | {_fmt(mean('sim_duration_s'), 1)} | "
            f"{_fmt(_mean(d for d, _ in p90), 1)} | "
            f"{_fmt(_mean(t for _, t in p90), 1)} |"
        )
    lines += [
        "",
        "Per world, mean ± std over seeds:",
        "",
        "| world | planner | completed | explored (%) | distance (m) | time to 90 % (s) "
        "| distance to 90 % (m) |",
        "|---|---|---|---|---|---|---|",
    ]
    for world in dict.fromkeys(r.get("world", "") for r in rows):
        for planner in dict.fromkeys(r["planner"] for r in rows):
            sel = [
                (r, x)
                for r, x in zip(rows, to90, strict=True)
                if (r.get("world", ""), r["planner"]) == (world, planner)
            ]
            if not sel:
                continue
            ms = [r["metrics"] for r, _ in sel]
            lines.append(
                f"| {world} | {planner} | {sum(m.get('verdict') == 'completed' for m in ms)} of {len(ms)} | "
                f"{mean_std(m.get('explored_percent') for m in ms)} | "
                f"{mean_std(m.get('distance_m') for m in ms)} | "
                f"{mean_std((t for _, (_, t) in sel))} | "
                f"{mean_std((d for _, (d, _) in sel))} |"
            )
    return "\n".join(lines) + "\n"


def plot_exploration(rows: list[dict], path: Path) -> None:
    """Explored volume against distance travelled and against time, one line per run, one row of
    two panels per world (their volumes differ), a colour per planner named once in the legend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {"cop": "tab:blue", "tsp": "tab:orange", "greedy": "tab:green"}
    drawn = [(row, series) for row in rows if (series := row["metrics"].get("explored_series"))]
    if not drawn:  # no run explored anything (every run failed, say): no empty plot
        return
    worlds = list(dict.fromkeys(row.get("world", "") for row, _ in drawn))
    fig, axes = plt.subplots(len(worlds), 2, figsize=(11, 3.6 * len(worlds)), squeeze=False)
    for row, series in drawn:
        s = np.array(series, dtype=float)
        by_distance, by_time = axes[worlds.index(row.get("world", ""))]
        colour = colours.get(row["planner"])
        by_distance.plot(s[:, 1], s[:, 2], color=colour, label=row["planner"], alpha=0.7)
        by_time.plot(s[:, 0], s[:, 2], color=colour, label=row["planner"], alpha=0.7)
    for world, (by_distance, by_time) in zip(worlds, axes, strict=True):
        by_distance.set_xlabel("distance travelled (m)")
        by_time.set_xlabel("time (s)")
        for ax in (by_distance, by_time):
            ax.set_ylabel("explored volume (m³)")
            ax.set_title(f"{world + ': ' if world else ''}one line per seed")
            handles, labels = ax.get_legend_handles_labels()
            once = dict(zip(labels, handles, strict=True))  # a planner's seeds share its colour
            ax.legend(once.values(), once.keys(), fontsize=8, loc="lower right")
    fig.suptitle("Exploration progress by planner")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# -- PAMS vs the prior-visit baseline (paper 2 Fig. 9) ----------------------------------------


def pams_comparison(
    specs: list[str],
    registry: Registry,
    seeds: list[int],
    out: Path,
    planners: tuple[str, ...] = ("pams", "prior_visit"),
    overrides: list[str] = (),
    log: Callable[[str], None] = print,
    runner: FlightRunner = SERIAL,
    resume: str | None = None,
) -> Path:
    """Fly every mission (one simulated world each) with PAMS and the baseline for each seed.

    The prior map both planners visit is one amslam built: first an overhead survey of the world
    (paper 2 §V: a prior map "which could come from the high-altitude UAV"; the multi-robot
    experiment's overhead robot, :func:`amslam.apps.multirobot.team_overrides`), then each
    planner flight with ``planner.prior_objects`` set to the survey's ``landmarks.json``. The
    ``objects`` block of each run's metrics (shape landmarks against the world's true shapes)
    fills a table like paper 2 Fig. 9: dimension error mean and standard deviation and the share
    of objects mapped, per world, per class and over all data.
    """
    from amslam.apps.multirobot import team_overrides

    folder = experiment_folder(out, "pams", specs[0] if len(specs) == 1 else "worlds", resume)
    worlds = [(m, s) for m in specs for s in seeds]
    surveys = [
        Flight(m, tuple(team_overrides(m, registry, 1, "heterogeneous", s, overrides, scratch=folder)[0]))
        for m, s in worlds
    ]
    log("  overhead surveys (the prior maps):")
    surveyed = fly_all(surveys, folder, runner, log, registry)
    priors = {world: _prior_map(rec) for world, rec in zip(worlds, surveyed, strict=True)}
    cases = [(m, s, p) for m, s in worlds for p in planners if priors[(m, s)] is not None]
    flights = [
        Flight(m, (*overrides, f"seed={s}", f"planner.plugin={p}", f"planner.prior_objects={priors[(m, s)]}"))
        for m, s, p in cases
    ]
    log("  planner flights:")
    flown = dict(zip(cases, fly_all(flights, folder, runner, log, registry), strict=True))
    rows = []
    for (m, s), survey in zip(worlds, surveyed, strict=True):
        for p in planners:
            # no prior map, no flight: the survey's failure is each planner's row
            rec = flown.get((m, s, p)) or {"overrides": [], "run_dir": None, "metrics": _no_prior(survey)}
            rows.append({"world": Path(m).stem, "seed": s, "planner": p, "survey": survey["run_dir"], **rec})
    (folder / "results.json").write_text(json.dumps(rows, indent=2, default=str))
    surveys_md = survey_table([(Path(m).stem, s) for m, s in worlds], surveyed)
    flown_all = [*surveyed, *flown.values()]
    text = pams_table(rows, planners) + "\n" + pams_flights_table(rows) + "\n" + surveys_md
    (folder / "table.md").write_text(text + code_note(flown_all))
    return folder


def pams_flights_table(rows: list[dict]) -> str:
    """Per planner flight: its verdict, Fig. 9 error and vehicles mapped, its length, and the
    trajectory's error, SLAM's against VIO's (RMS at the key poses and at the end), with how
    often SLAM stayed below VIO per planner (the summary table pools the objects and hides a
    flight whose SLAM drifted)."""
    lines = [
        "Per flight: vehicles' Fig. 9 error, vehicles mapped (discovered) of those in the world,"
        " path length, trajectory error SLAM / VIO (RMS at the key poses; at the end)",
        "",
        "| world | seed | planner | verdict | Fig. 9 err. (m) | vehicles mapped | path (m)"
        " | RMS SLAM / VIO (m) | end SLAM / VIO (m) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    below: dict[str, tuple[list[bool], list[bool]]] = {}

    def pair(slam: Any, vio: Any, counted: list[bool]) -> str:
        if slam is None or vio is None:
            return f"{_fmt(slam)} / {_fmt(vio)}"
        counted.append(slam < vio)
        return f"{_fmt(slam)} / {_fmt(vio)}{'' if slam < vio else ' (above)'}"

    for r in rows:
        m = r["metrics"]
        o = (m.get("objects") or {}).get("overall") or {}
        found = f" ({o['fig9_discovered']})" if "fig9_discovered" in o else ""
        mapped = f"{o['fig9_mapped']}{found} of {o['fig9_objects']}" if "fig9_mapped" in o else "—"
        t, e = m.get("trajectory_error") or {}, m.get("final_error") or {}
        rms, end = below.setdefault(r["planner"], ([], []))
        lines.append(
            f"| {r['world']} | {r['seed']} | {r['planner']} | {m.get('verdict', '?')} | "
            f"{_fmt(o.get('fig9_error_mean_m'))} | {mapped} | {_fmt(m.get('distance_m'), 1)} | "
            f"{pair(t.get('slam_rms_m'), t.get('vio_rms_m'), rms)} | "
            f"{pair(e.get('slam_position_m'), e.get('vio_position_m'), end)} |"
        )
    counts = ", ".join(
        f"{p} {sum(rms)} of {len(rms)} by RMS, {sum(end)} of {len(end)} at the end"
        for p, (rms, end) in below.items()
    )
    return "\n".join([*lines, "", f"SLAM below VIO: {counts or '—'}", ""])


def survey_table(worlds: list[tuple[str, int]], surveyed: list[dict[str, Any]]) -> str:
    """The prior maps the planners were given: per world and seed, the survey's verdict and, per
    shaped class, its landmarks, the true objects they mapped and their duplicates (a prior map's
    duplicates and misses are targets visited twice or never)."""
    lines = [
        "Prior maps (overhead surveys): landmarks / objects mapped (discovered, the map's drift taken"
        " out) of objects / duplicates, per class",
        "",
        "| world | seed | survey | classes |",
        "|---|---|---|---|",
    ]
    for (world, seed), rec in zip(worlds, surveyed, strict=True):
        m = rec["metrics"]
        per_class = "; ".join(
            f"{c}: {b.get('landmarks', '?')} / {b.get('mapped', '?')}"
            + (f" ({b['discovered']})" if "discovered" in b else "")
            + f" of {b.get('objects', '?')} / "
            f"{b.get('duplicates', '?')}"
            for c, b in sorted((m.get("objects") or {}).items())
            if c != "overall"
        )
        lines.append(f"| {world} | {seed} | {m.get('verdict', '?')} | {per_class or '—'} |")
    return "\n".join(lines) + "\n"


def _prior_map(survey: dict[str, Any]) -> str | None:
    """The survey's ``landmarks.json`` (absolute), or None when the survey left none."""
    if survey["run_dir"] is None:
        return None
    path = (Path(survey["run_dir"]) / "landmarks.json").resolve()
    return str(path) if path.is_file() else None


def _no_prior(survey: dict[str, Any]) -> dict[str, Any]:
    why = (
        survey["metrics"].get("error") or f"the survey ended {survey['metrics'].get('verdict')} without a map"
    )
    return {"verdict": "failed", "error": f"no prior map: {why}"}


def pool_errors(blocks: list[dict], metric: str = "dims_error", mapped: str = "mapped") -> dict[str, float]:
    """Pool per-run ``{mapped, objects, <metric>_mean_m, <metric>_std_m}`` over runs.

    Means weight each run by its mapped objects; the pooled std comes from the pooled second
    moment (``E[e²] = σ² + μ²`` per run), so it equals the std over all objects together.
    ``mapped`` names the count that goes with ``metric`` (``fig9_mapped`` for the overall
    ``fig9_error``, which counts vehicles only).
    """
    count = "objects" if mapped == "mapped" else mapped.replace("_mapped", "_objects")
    n = np.array([b.get(mapped, 0) for b in blocks], float)
    objects = float(sum(b.get(count, 0) for b in blocks))
    has = [b for b in blocks if f"{metric}_mean_m" in b and b.get(mapped, 0) > 0]
    out = {"mapped": float(n.sum()), "objects": objects}
    found = mapped.replace("mapped", "discovered")  # objects paired once the map's drift is out
    if blocks and all(found in b for b in blocks if b.get(count, 0)):
        out["discovered"] = float(sum(b.get(found, 0) for b in blocks))
    if has:
        w = np.array([b[mapped] for b in has], float)
        m = np.array([b[f"{metric}_mean_m"] for b in has])
        s = np.array([b[f"{metric}_std_m"] for b in has])
        mean = float(np.sum(w * m) / w.sum())
        second = float(np.sum(w * (s**2 + m**2)) / w.sum())
        out["mean"], out["std"] = mean, float(np.sqrt(max(second - mean**2, 0.0)))
    return out


def pams_table(rows: list[dict], planners: tuple[str, ...] = ("pams", "prior_visit")) -> str:
    """Markdown like paper 2 Fig. 9: one column per world and one for all data; ``a / b`` cells
    compare the planners in the order given.

    The error of the overall rows and of cuboid classes is paper 2 Fig. 9's: a vehicle's
    |Δlength| and |Δwidth| averaged (``fig9_error`` of the ``objects`` metrics), over vehicles
    only; cylinder classes get their diameter error (``dims_error``) in rows of their own.
    """
    worlds = list(dict.fromkeys(r["world"] for r in rows))
    classes = sorted({c for r in rows for c in (r["metrics"].get("objects") or {}) if c != "overall"})
    models = {
        c: b.get("model")
        for r in rows
        for c, b in (r["metrics"].get("objects") or {}).items()
        if c != "overall"
    }

    def pooled(world: str | None, planner: str, cls: str) -> dict[str, float]:
        blocks = [
            (r["metrics"].get("objects") or {}).get(cls, {})
            for r in rows
            if r["planner"] == planner and (world is None or r["world"] == world)
        ]
        if cls == "overall":
            if any("fig9_mapped" in b for b in blocks):
                return pool_errors(blocks, "fig9_error", "fig9_mapped")
            return pool_errors(blocks)  # runs measured before the Fig. 9 metric existed
        return pool_errors(blocks, "fig9_error" if models.get(cls) == "cuboid" else "dims_error")

    def cell(world: str | None, cls: str, what: str) -> str:
        vals = []
        for p in planners:
            d = pooled(world, p, cls)
            if what in ("mapped", "discovered"):
                ok = d["objects"] and what in d
                vals.append(f"{100 * d[what] / d['objects']:.0f} %" if ok else "—")
            else:
                vals.append(f"{d[what]:.2f} m" if what in d else "—")
        return " / ".join(vals)

    cols = [*worlds, None]
    head = " / ".join(planners)
    lines = [
        f"Object model error and objects mapped ({head}), like paper 2 Fig. 9. Err.: per vehicle"
        " mean |Δlength|, |Δwidth| (overall = vehicles); for cylinder classes: |Δdiameter|."
        " Obj. mapped: paired with a landmark within 1.5 m; discovered: the same once the map's drift"
        " (one rigid 2-D transform) is taken out",
        "",
        "| measure | " + " | ".join(w or "all data" for w in cols) + " |",
        "|---|" + "---|" * len(cols),
    ]
    for cls in ["overall", *classes]:
        label = "" if cls == "overall" else f" — {cls}"
        rows_of = (
            ("mean", "Err. mean"),
            ("std", "Err. std. dev."),
            ("mapped", "Obj. mapped"),
            ("discovered", "Obj. discovered"),
        )
        for what, name in rows_of:
            lines.append(f"| {name}{label} | " + " | ".join(cell(w, cls, what) for w in cols) + " |")
    dist = {
        p: _mean(r["metrics"].get("distance_m") or None for r in rows if r["planner"] == p) for p in planners
    }
    lines += ["", "Mean path length: " + ", ".join(f"{p} {_fmt(d, 1)} m" for p, d in dist.items()), ""]
    return "\n".join(lines)


# -- registration ------------------------------------------------------------------------------


def _seeds(args) -> list[int]:
    return list(range(args.first_seed, args.first_seed + args.seeds))


def _how(args) -> dict[str, Any]:
    """The keyword arguments every experiment here takes from the command line."""
    return {"overrides": args.set or [], "runner": FlightRunner.from_args(args), "resume": args.resume}


@amslam.hookimpl
def amslam_experiments():
    return {
        "slc-ablation": Experiment(
            "one or more missions with semantic loop closure on and off (paper 1 Tables I, II, Fig. 7)",
            lambda args, registry: slc_ablation(
                [args.mission, *args.more], registry, _seeds(args), Path(args.out), **_how(args)
            ),
            flight_arguments,
            several_missions=True,
        ),
        "planners": Experiment(
            "one or more missions with each exploration planner (COP, TSP, greedy)",
            lambda args, registry: planner_comparison(
                [args.mission, *args.more], registry, _seeds(args), Path(args.out), **_how(args)
            ),
            flight_arguments,
            several_missions=True,
        ),
        "calibrate": Experiment(
            "choose one parameter's value on training seeds and judge it on held-out seeds",
            calibration.run_from_args,
            calibration.calibration_arguments,
            several_missions=True,
        ),
        "pams": Experiment(
            "PAMS against the prior-visit baseline on one or more worlds (paper 2 Fig. 9)",
            lambda args, registry: pams_comparison(
                [args.mission, *args.more], registry, _seeds(args), Path(args.out), **_how(args)
            ),
            flight_arguments,
            several_missions=True,
        ),
    }
