"""``amslam experiment calibrate``: choose one parameter's value on training seeds, judge it on others.

A parameter without a derivation (COP's ``slc_scale``, its ``budget_factor``) is set by flying:
every candidate value on the training seeds, the best by one metric of ``metrics.json`` chosen
among the values whose every training flight completed (and met each ``--require``), then the
chosen value and the one it would replace flown on held-out seeds it never saw. Choosing on the
same flights it is judged on would report the noise it was chosen for (one flight's end error
swings by tenths of a metre between seeds), so the held-out table is the result; the training
table only says how the choice was made.

The experiment folder holds ``results.json`` (every flight, the choice and why), ``table.md``
(training and held-out tables, the verdict) and the run folders. Nothing is written into the
mission: the table says which line to change.
"""

from __future__ import annotations

import argparse
import json
import operator
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from amslam.apps.flights import SERIAL, Flight, FlightRunner, experiment_folder, fly_all
from amslam.apps.tables import mean_std
from amslam.errors import AmslamError, MissionError
from amslam.registry import Registry

#: what a calibration minimises unless told: the SLAM position error over the whole flight
DEFAULT_METRIC = "trajectory_error.slam_rms_m"

_OPERATORS = {">=": operator.ge, "<=": operator.le, ">": operator.gt, "<": operator.lt}


@dataclass(frozen=True)
class Requirement:
    """``METRIC>=VALUE`` (or ``<=``, ``>``, ``<``): a bound every training flight of a value must
    meet for the value to be chosen (``explored_percent>=95``: no value that explores less)."""

    metric: str
    op: str
    bound: float

    @classmethod
    def parse(cls, text: str) -> Requirement:
        m = re.fullmatch(r"\s*([\w.]+)\s*(>=|<=|>|<)\s*([-+0-9.eE]+)\s*", text)
        if not m:
            raise AmslamError(
                f"--require {text!r}: expected METRIC>=NUMBER (or <=, >, <), e.g. explored_percent>=95"
            )
        try:
            bound = float(m.group(3))
        except ValueError:
            raise AmslamError(f"--require {text!r}: {m.group(3)!r} is not a number") from None
        return cls(m.group(1), m.group(2), bound)

    def met(self, metrics: dict[str, Any]) -> bool:
        value = metric_of(metrics, self.metric)
        return value is not None and _OPERATORS[self.op](value, self.bound)

    def __str__(self) -> str:
        return f"{self.metric} {self.op} {self.bound:g}"


def _at(config: dict[str, Any], path: str) -> Any:
    """The value at a dotted ``path`` of a nested dict (a mission's resolved config, a flight's
    metrics); KeyError naming the first missing part."""
    node: Any = config
    for part in path.split("."):
        if not isinstance(node, dict) or part not in node:
            raise KeyError(part)
        node = node[part]
    return node


def metric_of(metrics: dict[str, Any], path: str) -> float | None:
    """The number at a dotted ``path`` of a flight's ``metrics.json`` (``final_error.slam_position_m``);
    None when the flight did not record it or it is not a finite number."""
    try:
        node = _at(metrics, path)
    except KeyError:
        return None
    if isinstance(node, bool) or not isinstance(node, int | float) or not np.isfinite(node):
        return None
    return float(node)


def _value_text(value: Any) -> str:
    """A value as ``--set`` takes it (YAML): ``10.0``, ``true``, ``[1, 2]``."""
    return json.dumps(value)


def check_values(
    specs: list[str], registry: Registry, param: str, values: list[str], overrides: list[str]
) -> tuple[list[Any], Any]:
    """Each value as the mission validates it, and the value the missions fly without the
    calibration (the one a choice would replace). Every value is checked on every mission before
    anything flies: a value a mission refuses is one error naming the mission and the value.

    Raises:
        MissionError: a value refused, the parameter not part of a mission, or missions that fly
            different values of it (there would be no one value to replace).
    """
    from amslam.mission import load_mission

    baselines = []
    for spec in specs:
        try:
            baselines.append(_at(load_mission(spec, registry, list(overrides)).resolved(), param))
        except KeyError:
            raise MissionError(
                [
                    f"--param {param}: mission {spec!r} has no such parameter "
                    "(`amslam dump-config KIND PLUGIN` lists a backend's)"
                ]
            ) from None
    if any(b != baselines[0] for b in baselines[1:]):
        flown = ", ".join(f"{s}: {b!r}" for s, b in zip(specs, baselines, strict=True))
        raise MissionError(
            [f"--param {param}: the missions fly different values ({flown}); calibrate them apart"]
        )
    validated = []
    for text in values:
        seen = None
        for spec in specs:
            try:
                mission = load_mission(spec, registry, [*overrides, f"{param}={text}"])
            except MissionError as exc:
                raise MissionError([f"--values {text}: {line}" for line in exc.problems]) from None
            seen = _at(mission.resolved(), param)
        validated.append(seen)
    if len({_value_text(v) for v in validated}) < len(validated):
        raise MissionError([f"--values {','.join(values)}: a value is given twice"])
    return validated, baselines[0]


def calibrate(
    specs: list[str],
    registry: Registry,
    param: str,
    values: list[str],
    train_seeds: list[int],
    held_out_seeds: list[int],
    out: Path,
    metric: str = DEFAULT_METRIC,
    maximise: bool = False,
    requirements: list[Requirement] = (),
    overrides: list[str] = (),
    log: Callable[[str], None] = print,
    runner: FlightRunner = SERIAL,
    resume: str | None = None,
) -> Path:
    """Fly every value on the training seeds, choose, fly the choice and the value it would replace
    on the held-out seeds; write ``results.json`` and ``table.md``."""
    if set(train_seeds) & set(held_out_seeds):
        raise AmslamError("the held-out seeds must differ from the training seeds")
    candidates, baseline = check_values(specs, registry, param, values, list(overrides))
    folder = experiment_folder(out, "calibrate", specs[0] if len(specs) == 1 else "worlds", resume)
    log(
        f"calibrating {param} over {', '.join(map(_value_text, candidates))}"
        f" (flown now: {_value_text(baseline)})"
    )

    def fly(cases: list[tuple[str, int, Any]]) -> list[dict[str, Any]]:
        flights = [
            Flight(s, (*overrides, f"seed={seed}", f"{param}={_value_text(v)}")) for s, seed, v in cases
        ]
        flown = fly_all(flights, folder, runner, log, registry)
        return [
            {"world": Path(s).stem, "seed": seed, "value": v, **rec}
            for (s, seed, v), rec in zip(cases, flown, strict=True)
        ]

    log(f"training seeds {train_seeds}")
    training = fly([(s, seed, v) for s in specs for seed in train_seeds for v in candidates])
    scores = score_values(training, candidates, metric, requirements)
    chosen, comparison = choose(candidates, scores, baseline, maximise)
    held_out: list[dict[str, Any]] = []
    if chosen is not None and held_out_seeds:
        judged = [chosen] + ([comparison] if comparison is not None else [])
        log(
            f"chose {_value_text(chosen)}; held-out seeds {held_out_seeds}:"
            f" {', '.join(map(_value_text, judged))}"
        )
        held_out = fly([(s, seed, v) for s in specs for seed in held_out_seeds for v in judged])
    result = {
        "param": param,
        "values": candidates,
        "flown_before": baseline,
        "metric": metric,
        "maximise": maximise,
        "requirements": [str(r) for r in requirements],
        "scores": {_value_text(v): s for v, s in zip(candidates, scores, strict=True)},
        "chosen": chosen,
        "compared_with": comparison,
        "training": training,
        "held_out": held_out,
    }
    (folder / "results.json").write_text(json.dumps(result, indent=2, default=str))
    (folder / "table.md").write_text(calibration_table(result))
    return folder


def score_values(
    rows: list[dict[str, Any]], values: list[Any], metric: str, requirements: list[Requirement] = ()
) -> list[dict[str, Any]]:
    """Per value: its training flights' metric (mean, std, n) and whether it may be chosen (every
    flight completed, measured the metric and met every requirement) or why not."""
    out = []
    for v in values:
        mine = [r for r in rows if _value_text(r["value"]) == _value_text(v)]
        figures = [metric_of(r["metrics"], metric) for r in mine]
        why = []
        if bad := [r for r in mine if r["metrics"].get("verdict") != "completed"]:
            why.append(
                f"{len(bad)} of {len(mine)} flights did not complete ("
                + "; ".join(
                    f"{r['world']} seed {r['seed']}: {str(r['metrics'].get('verdict'))[:60]}" for r in bad
                )
                + ")"
            )
        if missing := sum(f is None for f in figures):
            why.append(f"{missing} flight(s) did not measure {metric}")
        for req in requirements:
            if failed := [r for r in mine if not req.met(r["metrics"])]:
                why.append(f"{len(failed)} flight(s) miss {req}")
        finite = [f for f in figures if f is not None]
        out.append(
            {
                "mean": float(np.mean(finite)) if finite else None,
                "std": float(np.std(finite)) if finite else None,
                "n": len(finite),
                "eligible": not why and bool(mine),
                "why_not": "; ".join(why),
            }
        )
    return out


def choose(
    values: list[Any], scores: list[dict[str, Any]], baseline: Any, maximise: bool = False
) -> tuple[Any, Any]:
    """The best eligible value by its training mean, and the value the held-out seeds compare it
    with: the one flown before the calibration when that is another, else the runner-up (None if
    there is none). ``(None, None)`` when no value may be chosen."""
    ranked = sorted(
        (i for i, s in enumerate(scores) if s["eligible"]),
        key=lambda i: -scores[i]["mean"] if maximise else scores[i]["mean"],
    )
    if not ranked:
        return None, None
    chosen = values[ranked[0]]
    if _value_text(chosen) != _value_text(baseline):
        return chosen, baseline
    return chosen, values[ranked[1]] if len(ranked) > 1 else None


#: the columns every table shows besides the calibrated metric: (heading, metrics.json path, digits)
CONTEXT_COLUMNS = (
    ("explored (%)", "explored_percent", 1),
    ("time (s)", "sim_duration_s", 0),
    ("distance (m)", "distance_m", 0),
    ("SLAM end error (m)", "final_error.slam_position_m", 3),
    ("VIO RMS (m)", "trajectory_error.vio_rms_m", 3),
)


def _value_rows(rows: list[dict[str, Any]], values: list[Any], metric: str) -> list[str]:
    """One table row per value (and world, when there are several): flights completed, the metric
    and the context columns, mean ± std over seeds."""
    worlds = list(dict.fromkeys(r["world"] for r in rows))
    lines = []
    for v in values:
        for world in [*worlds, "all"] if len(worlds) > 1 else worlds:
            mine = [
                r for r in rows if _value_text(r["value"]) == _value_text(v) and world in (r["world"], "all")
            ]
            if not mine:
                continue
            done = sum(r["metrics"].get("verdict") == "completed" for r in mine)
            cells = [mean_std([metric_of(r["metrics"], metric) for r in mine], 3)] + [
                mean_std([metric_of(r["metrics"], path) for r in mine], digits)
                for _, path, digits in _context(metric)
            ]
            lines.append(
                f"| {_value_text(v)} | {world} | {done} of {len(mine)} | " + " | ".join(cells) + " |"
            )
    return lines


def _context(metric: str) -> tuple[tuple[str, str, int], ...]:
    """The context columns but the calibrated metric's own (``sim_duration_s`` is one)."""
    return tuple(c for c in CONTEXT_COLUMNS if c[1] != metric)


def _header(param: str, metric: str) -> list[str]:
    heads = [param, "world", "completed", metric] + [h for h, _, _ in _context(metric)]
    return ["| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]


def paired(
    rows: list[dict[str, Any]], chosen: Any, other: Any, metric: str
) -> list[tuple[str, int, float, float]]:
    """``(world, seed, chosen's metric, other's metric)`` for every held-out seed both measured."""
    by = {(r["world"], r["seed"], _value_text(r["value"])): metric_of(r["metrics"], metric) for r in rows}
    out = []
    for world, seed in dict.fromkeys((r["world"], r["seed"]) for r in rows):
        a, b = by.get((world, seed, _value_text(chosen))), by.get((world, seed, _value_text(other)))
        if a is not None and b is not None:
            out.append((world, seed, a, b))
    return out


def held_out_verdict(gains: np.ndarray) -> str:
    """One sentence on paired differences (negative: the chosen value is better): confirmed when
    the mean gain is more than two standard errors of the paired mean (about a 95 % one-sided
    test for five seeds or more), "within the seeds' noise" when better on average but not by
    that much, else not confirmed."""
    if not len(gains):
        return "**Not judged**: no held-out seed was measured by both values."
    mean = float(gains.mean())
    se = float(gains.std(ddof=1) / np.sqrt(len(gains))) if len(gains) > 1 else float("inf")
    if mean < -1e-12 and mean < -2.0 * se:
        return "**The held-out seeds confirm the choice.**"
    if mean < -1e-12:
        return (
            f"**Better on average, within the seeds' noise** (paired standard error {se:.3f}): "
            "more seeds would tell."
        )
    return (
        "**The held-out seeds do not confirm the choice**: keep the value flown before, or calibrate "
        "on more seeds."
    )


def calibration_table(result: dict[str, Any]) -> str:
    """``table.md``: the choice, the training table (how it was made) and the held-out table (the
    result), with the verdict of the held-out seeds in one sentence."""
    param, metric, values = result["param"], result["metric"], result["values"]
    chosen, other = result["chosen"], result["compared_with"]
    better = "higher" if result["maximise"] else "lower"
    lines = [
        f"# Calibration of `{param}`",
        "",
        f"Chosen by the mean of `{metric}` ({better} is better) over the training seeds, among values "
        "whose every training flight completed"
        + (
            " and met " + ", ".join(f"`{r}`" for r in result["requirements"])
            if result["requirements"]
            else ""
        )
        + f". Flown before the calibration: `{_value_text(result['flown_before'])}`.",
        "",
        "## Training seeds (how the value was chosen)",
        "",
        *_header(param, metric),
        *_value_rows(result["training"], values, metric),
        "",
    ]
    for v in values:
        score = result["scores"][_value_text(v)]
        if not score["eligible"]:
            lines.append(f"- `{_value_text(v)}` not eligible: {score['why_not']}")
    if chosen is None:
        lines += ["", "**No value chosen**: none was eligible.", ""]
        return "\n".join(lines)
    lines += ["", f"**Chosen: `{param}: {_value_text(chosen)}`**", ""]
    if not result["held_out"]:
        return "\n".join([*lines, "Not judged: no held-out seeds were flown.", ""])
    judged = [chosen] + ([other] if other is not None else [])
    lines += [
        "## Held-out seeds (the result)",
        "",
        *_header(param, metric),
        *_value_rows(result["held_out"], judged, metric),
        "",
    ]
    requirements = [Requirement.parse(r) for r in result["requirements"]]
    for v, score in zip(judged, score_values(result["held_out"], judged, metric, requirements), strict=True):
        if not score["eligible"]:  # what the choice asked of training flights, asked of these too
            lines += [f"- `{_value_text(v)}` on the held-out seeds: {score['why_not']}", ""]
    if other is None:
        return "\n".join([*lines, "No other eligible value to compare with.", ""])
    pairs = paired(result["held_out"], chosen, other, metric)
    sign = -1.0 if result["maximise"] else 1.0
    diffs = np.array([a - b for _, _, a, b in pairs])
    wins = int(np.sum(sign * diffs < -1e-12))
    lines.append(
        f"Paired by seed, `{metric}` of `{_value_text(chosen)}` minus `{_value_text(other)}`: "
        + (f"{diffs.mean():+.3f} ± {diffs.std():.3f}" if len(diffs) else "—")
        + f"; {better} on {wins} of {len(pairs)} held-out flights. "
        + held_out_verdict(sign * diffs)
    )
    lines.append("")
    return "\n".join(lines)


def calibration_arguments(parser: argparse.ArgumentParser) -> None:
    """``--param``, ``--values``, ``--held-out``, ``--minimise``/``--maximise``, ``--require``, and
    the flight arguments (``--executor``...). ``--seeds`` and ``--first-seed`` give the training
    seeds; the held-out seeds follow them."""
    from amslam.apps.flights import flight_arguments

    parser.add_argument(
        "--param", required=True, metavar="KEY.PATH", help="the parameter, e.g. planner.slc_scale"
    )
    parser.add_argument(
        "--values", required=True, metavar="V1,V2,...", help="candidate values, comma-separated (YAML each)"
    )
    parser.add_argument(
        "--held-out",
        type=int,
        metavar="N",
        help="held-out seeds flown after the choice, following the training seeds (default: as many)",
    )
    goal = parser.add_mutually_exclusive_group()
    goal.add_argument(
        "--minimise", metavar="METRIC", help=f"metrics.json path to minimise (default {DEFAULT_METRIC})"
    )
    goal.add_argument("--maximise", metavar="METRIC", help="metrics.json path to maximise instead")
    parser.add_argument(
        "--require",
        action="append",
        type=_requirement,
        metavar="METRIC>=X",
        help="a bound every training flight of a value must meet (repeatable), e.g. explored_percent>=95",
    )
    flight_arguments(parser)


def _requirement(text: str) -> Requirement:
    """An argparse type: a ``--require`` refused in one line (argparse's own error) when it does
    not read."""
    try:
        return Requirement.parse(text)
    except AmslamError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def run_from_args(args: argparse.Namespace, registry: Registry) -> Path:
    """``amslam experiment calibrate`` as the command line gives it."""
    values = [v.strip() for v in args.values.split(",")]
    if len(values) < 2 or not all(values):
        raise AmslamError(f"--values {args.values!r}: give two or more values, comma-separated")
    held_out = args.seeds if args.held_out is None else args.held_out
    if held_out < 0:
        raise AmslamError(f"--held-out {held_out}: not a number of seeds")
    first_held_out = args.first_seed + args.seeds
    return calibrate(
        [args.mission, *args.more],
        registry,
        args.param,
        values,
        list(range(args.first_seed, first_held_out)),
        list(range(first_held_out, first_held_out + held_out)),
        Path(args.out),
        metric=args.maximise or args.minimise or DEFAULT_METRIC,
        maximise=bool(args.maximise),
        requirements=args.require or [],
        overrides=args.set or [],
        runner=FlightRunner.from_args(args),
        resume=args.resume,
    )
