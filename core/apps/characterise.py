"""``amslam characterise``: fit confidence and geometric-error models from simulated spiral flights
around specimen objects (paper 2 §IV-C); the work is :mod:`amslam.apps.characterisation`.

This module only declares the command: every ``amslam`` command line loads it, and the
characterisation imports the simulator's world, camera and detector, which only running the
command needs (issue #20).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import amslam
from amslam.cli import Command, whole_number


def _arguments(parser) -> None:
    parser.add_argument("mission", nargs="?", help="mission whose simulated camera and detector to use")
    parser.add_argument(
        "--out", required=True, help="models file to write (.npz; samples and plot beside it)"
    )
    parser.add_argument("--poses", type=whole_number(4), help="frames per spiral (default 240)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--classes",
        type=_names,
        help="classes to characterise, comma-separated (car, pole: solid specimens; chair, table, shelf,"
        " sofa: the procedural buildings' furniture); default car, pole, chair",
    )
    parser.add_argument(
        "--heights",
        type=_numbers,
        help="spiral heights above the ground, comma-separated, m (default 1.5,3,5)",
    )
    parser.add_argument("--range-min", type=_positive, help="radius where the spirals start, m (default 2)")
    parser.add_argument(
        "--keep",
        help="models file whose other classes go into --out unchanged (e.g. the packaged"
        " core/lib/models/default.npz when adding indoor classes)",
    )


def _names(text: str) -> list[str]:
    names = [t.strip() for t in text.split(",") if t.strip()]
    if not names:
        raise argparse.ArgumentTypeError("expected one or more class names, comma-separated")
    return names


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0 < value < math.inf:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def _numbers(text: str) -> list[float]:
    try:
        values = [_positive(t) for t in text.split(",") if t.strip()]
    except argparse.ArgumentTypeError:
        values = []
    if not values:
        raise argparse.ArgumentTypeError(f"expected positive numbers, comma-separated, got {text!r}")
    return values


def _run(args, registry) -> int:
    from amslam.apps.characterisation import characterise

    mission = None
    if args.mission:
        from amslam.apps.commands import load_with_registry

        mission = load_with_registry(args, registry)[0]
    characterise(
        Path(args.out),
        mission=mission,
        poses_per_spiral=args.poses,
        seed=args.seed,
        classes=args.classes,
        heights=args.heights,
        range_min=args.range_min,
        keep=Path(args.keep) if args.keep else None,
    )
    return 0


@amslam.hookimpl
def amslam_cli_commands():
    return {
        "characterise": Command("fit confidence and geometric-error models (paper 2 §IV-C)", _arguments, _run)
    }
