"""``amslam export``: a run folder in the formats other robotics tools read.

``amslam export RUN --mcap FILE`` writes the run as ROS 2 messages in an MCAP file that opens in
Foxglove and reads back with the ``mcap`` and ``rosbags`` readers, with no ROS installation
(:mod:`.mcap_file`; topics and frames in ``docs/interop.md``). The libraries come with the
``interop`` extra and are imported only when the command runs, so the command line stays fast.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import amslam
from amslam.cli import Command
from amslam.errors import AmslamError

INTEROP_HINT = "pip install amslam[interop]"
#: the interop extra's modules and the distributions that install them
DISTRIBUTIONS = {"mcap": "mcap", "mcap_ros2": "mcap-ros2-support", "rosbags": "rosbags"}


def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", help="run folder (written by `amslam run`), or a folder of them: the newest")
    parser.add_argument(
        "--mcap",
        metavar="FILE",
        help="write ROS 2 messages (TF, paths, odometry, maps, markers) and JSON (events, tree) to FILE",
    )
    parser.add_argument(
        "--ros-only",
        action="store_true",
        help="leave out the JSON channels (events, tree status, metrics): for rosbags and `ros2 bag play`",
    )


def _run(args: argparse.Namespace, registry) -> int:
    if args.mcap is None:
        raise AmslamError("export: nothing to write: give --mcap FILE.mcap")
    out = Path(args.mcap)
    if out.suffix != ".mcap":
        raise AmslamError(f"--mcap {out}: the file name must end in .mcap (Foxglove and rosbags go by it)")
    if out.is_dir():
        raise AmslamError(f"--mcap {out}: is a folder, give a file name")
    try:
        import mcap  # noqa: F401
        import mcap_ros2  # noqa: F401
        import rosbags  # noqa: F401
    except ImportError as exc:
        package = DISTRIBUTIONS.get(exc.name or "", exc.name)
        raise AmslamError(f"export --mcap needs {package}, which is not installed: {INTEROP_HINT}") from None
    from amslam.apps.export.mcap_file import write_mcap
    from amslam.apps.export.runfolder import read_run_folder
    from amslam.apps.viewer import resolve_run_folder

    folder, newest = resolve_run_folder(Path(args.run))  # a folder of runs: its newest, as `amslam view`
    if newest:
        print(f"newest run in {args.run}: {folder}")
    run = read_run_folder(folder)
    for warning in run.warnings:  # what is left out, before the wait for the writing
        print(f"warning: {warning}", file=sys.stderr)
    try:
        summary = write_mcap(run, out, ros_only=args.ros_only)
    except OSError as exc:
        raise AmslamError(f"--mcap {out}: cannot be written ({exc.strerror or exc})") from None
    total = sum(summary.counts.values())
    size = out.stat().st_size / 1e6
    print(f"wrote {out}: {total} messages on {len(summary.counts)} topics, {size:.1f} MB")
    width = max(len(t) for t in summary.counts)
    for topic in sorted(summary.counts):
        print(f"  {topic:<{width}}  {summary.counts[topic]:>6}  {summary.types[topic]}")
    print(f"camera mount (base_link → camera_optical): {run.camera.source}")
    return 0


@amslam.hookimpl
def amslam_cli_commands():
    return {
        "export": Command(
            "write a run folder as ROS 2 messages in MCAP (Foxglove, rosbags)", _arguments, _run
        )
    }
