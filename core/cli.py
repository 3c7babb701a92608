"""The ``amslam`` command line: a dispatcher over the commands plugins provide.

The kernel owns one subcommand, ``experiment``, which dispatches to the experiments plugins
provide through ``amslam_experiments`` (each an :class:`Experiment`: ``amslam experiment NAME
MISSION ...``). Every other one — ``run``, ``fly``, ``validate``, ``plugins``, ``dump-config``,
``tree``, ``view``, ``characterise`` and any third party's — comes through ``amslam_cli_commands``
as a :class:`Command`. The built-ins live in ``amslam.apps`` and register exactly as a third-party
distribution would.

``amslam --help`` lists what is installed. Errors amslam can explain are printed as
``error: ...`` lines with exit status 2, never as a traceback.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from amslam.errors import AmslamError, MissionError

if TYPE_CHECKING:
    from amslam.registry import Registry


@dataclass(frozen=True)
class Command:
    """One ``amslam`` subcommand.

    ``add_arguments`` declares its arguments on the subparser; ``run`` receives the parsed
    arguments and the registry the command line was built from, and returns the exit status.
    """

    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace, Registry], int]


@dataclass(frozen=True)
class Experiment:
    """One ``amslam experiment NAME``: a mission flown several ways, summarised in a folder.

    Every experiment takes ``MISSION [MORE ...]``, ``--seeds``, ``--first-seed``, ``--out`` and
    ``--set`` (see :func:`experiment_arguments`); ``add_arguments`` adds its own. ``run`` returns
    the experiment folder, which holds at least ``table.md``.
    """

    help: str
    run: Callable[[argparse.Namespace, Registry], Path]
    add_arguments: Callable[[argparse.ArgumentParser], None] = lambda parser: None


def experiment_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments every experiment takes."""
    parser.add_argument("mission", help="mission file, or the name of a packaged mission")
    parser.add_argument("more", nargs="*", help="further missions, for experiments over several worlds")
    parser.add_argument("--seeds", type=int, default=5, help="number of seeds (default 5)")
    parser.add_argument("--first-seed", type=int, default=1)
    parser.add_argument("--out", default="runs", help="folder that receives the experiment folder")
    parser.add_argument("--set", action="append", metavar="KEY.PATH=VALUE", help="override for every run")


def build_parser(registry: Registry) -> argparse.ArgumentParser:
    """The argument parser of every installed command."""
    parser = argparse.ArgumentParser(
        prog="amslam", description="Active metric-semantic SLAM for aerial robots: fly missions, replay runs."
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in sorted(registry.commands):
        command = registry.commands[name]
        command.add_arguments(sub.add_parser(name, help=command.help, description=command.help))
    if registry.experiments:
        help_ = "fly a mission several ways over several seeds and compare"
        experiments = sub.add_parser("experiment", help=help_, description=help_)
        names = experiments.add_subparsers(dest="experiment", required=True, metavar="NAME")
        for name in sorted(registry.experiments):
            experiment = registry.experiments[name]
            one = names.add_parser(name, help=experiment.help, description=experiment.help)
            experiment_arguments(one)
            experiment.add_arguments(one)
    return parser


def run_experiment(args: argparse.Namespace, registry: Registry) -> int:
    """``amslam experiment NAME ...``: run it, print its table and where its folder is."""
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    print(f"experiment {args.experiment} on {args.mission}, seeds {seeds}", flush=True)
    folder = registry.experiments[args.experiment].run(args, registry)
    print((folder / "table.md").read_text())
    print(f"experiment folder: {folder}")
    return 0


def main(argv: list[str] | None = None) -> int:
    from amslam.registry import build_plugin_manager

    try:
        registry = build_plugin_manager()
        args = build_parser(registry).parse_args(argv)
        if args.command == "experiment":
            return run_experiment(args, registry)
        return registry.commands[args.command].run(args, registry)
    except MissionError as exc:
        for problem in exc.problems:
            print(f"error: {problem}", file=sys.stderr)
        return 2
    except AmslamError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
