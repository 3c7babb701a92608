"""The ``amslam`` command line: a dispatcher over the commands plugins provide.

The kernel owns one subcommand, ``experiment``, which dispatches to the experiments plugins
provide through ``amslam_experiments`` (each an :class:`Experiment`: ``amslam experiment NAME
MISSION ...``). Every other one — ``run``, ``fly``, ``validate``, ``plugins``, ``dump-config``,
``tree``, ``view``, ``characterise`` and any third party's — comes through ``amslam_cli_commands``
as a :class:`Command`. The built-ins live in ``amslam.apps`` and register exactly as a third-party
distribution would.

``amslam --help`` lists what is installed; ``amslam --version`` (or ``python -m amslam
--version``) prints the installed version. What reaches stderr — a run's progress bar or status
line, warnings (Python's too, through ``logging``), errors — is chosen by ``--quiet`` (errors
only), ``--verbose`` (debug too) or ``--log-level LEVEL``, given before or after the subcommand;
stdout, a command's own output, is the same at every level. Exit statuses, for every subcommand:

====  ===========================================================================================
0     done (a run: its verdict is ``completed``)
1     a run failed, crashed or was aborted (its run folder says why)
2     bad input: an ``error: ...`` line says what and where, never a traceback
130   interrupted (Ctrl-C); 143 terminated (SIGTERM); 129 hung up (SIGHUP): a flight lands first
141   the output was closed early (piped into ``head``): amslam did not stop for it — a flight
      went on to its verdict and completed its run folder (``events.jsonl``: ``stdout_closed``),
      an experiment flew all its runs — but printed nothing more (:mod:`amslam.console`)
====  ===========================================================================================
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from amslam import console
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
    #: whether it flies several missions (``MISSION MORE ...``); if not, extra missions are refused
    several_missions: bool = False


def whole_number(minimum: int, maximum: int | None = None) -> Callable[[str], int]:
    """An argparse type: a whole number in [``minimum``, ``maximum``], refused in one line otherwise."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"{value} is not at least {minimum}")
        if maximum is not None and value > maximum:
            raise argparse.ArgumentTypeError(f"{value} is more than {maximum}")
        return value

    return parse


positive_int = whole_number(1)


def experiment_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments every experiment takes."""
    parser.add_argument("mission", help="mission file, or the name of a packaged mission")
    parser.add_argument("more", nargs="*", help="further missions, for experiments over several worlds")
    parser.add_argument("--seeds", type=positive_int, default=5, help="number of seeds (default 5)")
    parser.add_argument("--first-seed", type=whole_number(0), default=1)
    parser.add_argument("--out", default="runs", help="folder that receives the experiment folder")
    parser.add_argument("--set", action="append", metavar="KEY.PATH=VALUE", help="override for every run")


def log_level(text: str) -> str:
    """An argparse type: a ``--log-level`` name (any case), refused in one line otherwise."""
    if text.lower() not in console.LEVELS:
        raise argparse.ArgumentTypeError(f"{text!r} is not a level; levels are {', '.join(console.LEVELS)}")
    return text.lower()


def output_options(parser: argparse.ArgumentParser, *, on_subcommand: bool) -> None:
    """``--quiet``, ``--verbose``, ``--log-level``: accepted before the subcommand and after it.

    On a subcommand's parser their defaults are suppressed, so that one given before the
    subcommand is not reset by the subcommand's parser (argparse's sub-parsers write their
    defaults over the main parser's).
    """

    def default(value: object) -> object:
        return argparse.SUPPRESS if on_subcommand else value

    group = parser.add_argument_group("output (also accepted before the subcommand)")
    group.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        default=default(False),
        help="on stderr, errors only: no progress bar or status line, no warnings",
    )
    group.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        default=default(False),
        help="also debug messages, and warnings with their source line",
    )
    group.add_argument(
        "--log-level",
        type=log_level,
        metavar="LEVEL",
        default=default(None),
        help=f"what reaches stderr: {', '.join(console.LEVELS)} (default info; overrides -q and -v)",
    )


def _version() -> str:
    """``amslam X.Y.Z`` from the installed distribution's metadata (the source's when not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    from amslam import __version__

    try:
        return f"amslam {version('amslam')}"
    except PackageNotFoundError:
        return f"amslam {__version__}"


def build_parser(registry: Registry) -> argparse.ArgumentParser:
    """The argument parser of every installed command."""
    parser = argparse.ArgumentParser(
        prog="amslam", description="Active metric-semantic SLAM for aerial robots: fly missions, replay runs."
    )
    parser.add_argument("--version", action="version", version=_version())
    output_options(parser, on_subcommand=False)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def add_parser(on: argparse._SubParsersAction, name: str, help_: str) -> argparse.ArgumentParser:
        # "resolve": a third party's command that declares its own --quiet or -v keeps it
        one = on.add_parser(name, help=help_, description=help_, conflict_handler="resolve")
        output_options(one, on_subcommand=True)
        return one

    for name in sorted(registry.commands):
        command = registry.commands[name]
        command.add_arguments(add_parser(sub, name, command.help))
    if registry.experiments:
        experiments = add_parser(
            sub, "experiment", "fly a mission several ways over several seeds and compare"
        )
        names = experiments.add_subparsers(dest="experiment", required=True, metavar="NAME")
        for name in sorted(registry.experiments):
            experiment = registry.experiments[name]
            one = add_parser(names, name, experiment.help)
            experiment_arguments(one)
            experiment.add_arguments(one)
    return parser


def chosen_level(args: argparse.Namespace) -> str:
    """The level the output options ask for: ``--log-level``, else ``--verbose`` (debug) or
    ``--quiet`` (error), else info (a run's status line, warnings)."""
    if args.log_level:
        return args.log_level
    quiet, verbose = args.quiet is True, args.verbose is True  # a command's own --quiet may be no flag
    if quiet and verbose:
        raise AmslamError("--quiet and --verbose contradict each other: give one (or --log-level)")
    return "error" if quiet else "debug" if verbose else "info"


def run_experiment(args: argparse.Namespace, registry: Registry) -> int:
    """``amslam experiment NAME ...``: run it, print its table and where its folder is.

    Exit status 1 when it flew runs (run folders under ``<folder>/runs``) and none completed: a
    table of failures is no result.
    """
    experiment = registry.experiments[args.experiment]
    if args.more and not experiment.several_missions:
        extra = " ".join(args.more)
        raise AmslamError(f"experiment {args.experiment} flies one mission; also given: {extra}")
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    print(
        f"experiment {args.experiment} on {' '.join([args.mission, *args.more])}, seeds {seeds}", flush=True
    )
    started = time.time()
    try:
        folder = experiment.run(args, registry)
    except OSError as exc:
        # Flown runs are already whole run folders on disk; what failed is the summary (a full
        # disk): one line naming the file, exit 1 as for a run whose outputs could not all be
        # written, never a traceback. A write that fails on a full disk names no file: name the
        # experiment folder this call made.
        where = exc.filename or _newest_folder(Path(args.out), since=started) or args.out
        print(
            f"warning: experiment {args.experiment}: cannot write {where}: {exc.strerror or exc};"
            f" the runs flown so far are kept under {args.out}",
            file=sys.stderr,
        )
        return 1
    print((folder / "table.md").read_text())
    print(f"experiment folder: {folder}")
    verdicts = [_verdict(m) for m in sorted(folder.glob("runs/*/metrics.json"))]
    if verdicts and "completed" not in verdicts:
        print(f"error: none of the {len(verdicts)} runs completed ({verdicts[0]}, ...)", file=sys.stderr)
        return 1
    return 0


def _newest_folder(parent: Path, since: float) -> Path | None:
    """The newest folder in ``parent`` made at ``since`` or later (None if none)."""
    try:
        made = [p for p in parent.iterdir() if p.is_dir() and p.stat().st_mtime >= since - 1]
    except OSError:
        return None
    return max(made, key=lambda p: p.stat().st_mtime, default=None)


def _verdict(metrics_file: Path) -> str:
    import json

    try:
        return str(json.loads(metrics_file.read_text()).get("verdict", "no verdict"))
    except (OSError, ValueError, AttributeError):
        return f"unreadable {metrics_file.name}"


#: the signals that stop amslam the way Ctrl-C does
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class Terminated(KeyboardInterrupt):
    """A stop signal (SIGINT, SIGTERM, SIGHUP), raised where the program is: a flight lands, the
    run folder is completed with the verdict, and the process exits 128 + the signal's number.
    Being a KeyboardInterrupt, it takes Ctrl-C's path through every ``except KeyboardInterrupt``."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


#: the first stop signal received by this process, if any
received_signal: int | None = None


def _stop(signum: int, frame: object) -> None:
    global received_signal
    if received_signal is not None:
        # Already stopping (landing, writing the run folder): a second Ctrl-C must not cut that
        # short and leave a torn run folder. SIGKILL remains for the impatient.
        first = signal.Signals(received_signal).name
        print(f"already stopping after {first}: landing and saving the run folder", file=sys.stderr)
        return
    received_signal = signum
    raise Terminated(signum)


def main(argv: list[str] | None = None) -> int:
    global received_signal
    received_signal = None
    previous = {signum: signal.signal(signum, _stop) for signum in STOP_SIGNALS}
    try:
        with console.guarded():
            return _main(argv)
    finally:  # an embedding process (a test calling main) gets its own handlers back
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _log_start(registry: Registry) -> None:
    """With ``--verbose``: what runs, and which plugins loaded from where."""
    log = logging.getLogger("amslam.cli")
    if not log.isEnabledFor(logging.DEBUG):
        return
    log.debug(f"{_version()} on Python {sys.version.split()[0]} ({sys.executable})")
    for name, dist in sorted(registry.distributions.items()):
        log.debug(f"plugin {name} from {dist}")
    for name in sorted(registry.load_errors):
        log.debug(registry.load_errors[name])


def _main(argv: list[str] | None) -> int:
    from amslam.registry import build_plugin_manager

    try:
        registry = build_plugin_manager()
        args = build_parser(registry).parse_args(argv)
        with console.logging_to_stderr(chosen_level(args)):
            _log_start(registry)
            if args.command == "experiment":
                status = run_experiment(args, registry)
            else:
                status = registry.commands[args.command].run(args, registry)
        sys.stdout.flush()  # a closed pipe shows here (console.closed)
        if received_signal is not None:  # the command caught it and finished cleanly (a run landed)
            print(f"stopped by {signal.Signals(received_signal).name}", file=sys.stderr)
            return 128 + received_signal
        if console.closed:  # the command went on to its end; its output went nowhere
            return 141
        return status
    except MissionError as exc:
        for problem in exc.problems:
            print(f"error: {problem}", file=sys.stderr)
        return 2
    except AmslamError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # a pipe written to past the guarded sys.stdout / sys.stderr (a child's, a raw file
        # descriptor) lost its reader: stop quietly; stdout to /dev/null, so that the
        # interpreter's last flush at exit does not complain about it a second time
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.__stdout__.fileno())
        return 141
    except KeyboardInterrupt as exc:
        signum = exc.signum if isinstance(exc, Terminated) else signal.SIGINT
        print(f"stopped by {signal.Signals(signum).name}", file=sys.stderr)
        return 128 + signum


if __name__ == "__main__":
    sys.exit(main())
