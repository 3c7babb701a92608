"""``amslam characterise``: fit confidence and geometric-error models from simulated spiral flights
around specimen objects (paper 2 §IV-C); the work is :mod:`amslam.apps.characterisation`.

This module only declares the command: every ``amslam`` command line loads it, and the
characterisation imports the simulator's world, camera and detector, which only running the
command needs (issue #20).
"""

from __future__ import annotations

from pathlib import Path

import amslam
from amslam.cli import Command


def _arguments(parser) -> None:
    parser.add_argument("mission", nargs="?", help="mission whose simulated camera and detector to use")
    parser.add_argument(
        "--out", required=True, help="models file to write (.npz; samples and plot beside it)"
    )
    parser.add_argument("--poses", type=int, help="frames per spiral (default 240)")
    parser.add_argument("--seed", type=int, default=0)


def _run(args, registry) -> int:
    from amslam.apps.characterisation import characterise

    mission = None
    if args.mission:
        from amslam.apps.commands import load_with_registry

        mission = load_with_registry(args, registry)[0]
    characterise(Path(args.out), mission=mission, poses_per_spiral=args.poses, seed=args.seed)
    return 0


@amslam.hookimpl
def amslam_cli_commands():
    return {
        "characterise": Command("fit confidence and geometric-error models (paper 2 §IV-C)", _arguments, _run)
    }
