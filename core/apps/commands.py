"""The built-in ``amslam`` subcommands, registered through ``amslam_cli_commands`` exactly as a
third party's would be (see :mod:`amslam.cli`).

    amslam run MISSION [--out DIR] [--set key.path=value ...] [--rerun [--rrd [FILE]]]
    amslam fly MISSION [--out DIR] [--set key.path=value ...]   (a real vehicle, after a pre-flight check)
    amslam validate MISSION
    amslam plugins
    amslam dump-config KIND PLUGIN
    amslam tree MISSION [--format ascii|unicode|dot|svg|png] [--out FILE]
    amslam view RUN_DIR [--out FILE] [--screenshot PNG [--time T]] [--serve [--port N]] [--at T]
                        [--rerun [--rrd [FILE] | --web]]

MISSION is a YAML file or the name of a packaged mission (``demo``).
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import amslam
from amslam.cli import Command, whole_number
from amslam.errors import AmslamError
from amslam.registry import build_plugin_manager

log = logging.getLogger(__name__)


def load_with_registry(args, registry=None):
    """Build the registry honouring the mission's ``plugins.disable`` (from the file or ``--set``),
    then validate the mission.

    ``registry``, the one the command line was built from, is used as it is when the mission
    disables no plugin: building it again reads every installed distribution's entry points
    and registers every plugin a second time.
    """
    from amslam.errors import MissionError
    from amslam.mission import (
        apply_override,
        load_mission,
        parse_yaml,
        read_mission_text,
        resolve_mission_path,
    )

    disabled: list[str] = []
    try:
        path = resolve_mission_path(args.mission)
        raw = parse_yaml(read_mission_text(path), str(path))
        raw = dict(raw) if isinstance(raw, dict) else {}
        for assignment in getattr(args, "set", None) or []:
            apply_override(raw, assignment)
        section = raw.get("plugins")
        if isinstance(section, dict) and isinstance(section.get("disable"), list):
            disabled = [str(x) for x in section["disable"]]
    except MissionError:
        pass  # load_mission reports it, with the line
    if registry is None or disabled:
        registry = build_plugin_manager(disabled)
    mission = load_mission(args.mission, registry, getattr(args, "set", None) or [])
    for name in mission.model.plugins.optional:  # load_mission refused every other load error
        if name in registry.load_errors:
            log.warning(f"optional {registry.load_errors[name]}; going on without it")
    return mission, registry


def _live_rerun(args, registry) -> None:
    """``--rerun``: a live rerun view of this run only, registered in-process as its observer."""
    if args.rrd is not None and not args.rerun:
        raise AmslamError("--rrd needs --rerun")
    if not args.rerun:
        return
    from amslam.apps.rerun_view import LiveRerun, import_rerun
    from amslam.apps.rerun_view.sink import writable_file

    import_rerun()  # before flying: a missing rerun-sdk is one error line, not a run without its view
    if args.rrd:
        writable_file(Path(args.rrd))
    registry.pm.register(
        LiveRerun(args.rrd, announce=lambda line: print(line, flush=True)), name="rerun_live"
    )


def cmd_run(args, registry) -> int:
    from amslam.runner import Runner

    mission, registry = load_with_registry(args, registry)
    _live_rerun(args, registry)
    print(f"flying mission {mission.name!r} ({mission.source})", flush=True)

    def announce(run_dir: Path) -> None:
        print(f"run folder: {run_dir}  (watch it live: amslam view {run_dir} --serve)", flush=True)

    # the progress bar on a terminal, a status line elsewhere: amslam.apps.status, a run observer
    result = Runner(mission, registry, Path(args.out), on_start=announce).run()
    m = result.metrics
    print(f"verdict: {result.verdict}")
    if "explored_percent" in m:
        share, distance = m["explored_percent"], m.get("distance_m")
        print(f"explored: {share} % of the reachable free volume, distance {distance} m")
    print(f"run folder: {result.run_dir}")
    if result.report.exists():  # not when the report application is disabled
        print(f"report: {result.report}")
    if "outputs_error" in m:  # a full disk, say: the streams and the verdict were kept
        print(
            f"warning: not every output of the run could be written ({m['outputs_error']}); "
            "events.jsonl says which",
            file=sys.stderr,
        )
        return 1
    return 0 if result.verdict == "completed" else 1


def cmd_fly(args, registry) -> int:
    """Fly a real vehicle: the pre-flight check first, refusing with every reason that failed."""
    import tempfile

    import numpy as np

    from amslam.interfaces import RunContext

    mission, registry = load_with_registry(args, registry)
    choice = mission.backends["platform"]
    cls = registry.backend_class("platform", choice.plugin)
    print(f"pre-flight check of {mission.name!r} ({mission.source})", flush=True)
    plugins = ", ".join(f"{kind}={c.plugin}" for kind, c in mission.backends.items())
    print(f"  ok    plugins loaded: {plugins}")
    if cls.simulated:
        raise AmslamError(f"refusing to fly: platform {choice.plugin!r} is simulated; use `amslam run`")
    if not hasattr(cls, "connect_and_check"):
        raise AmslamError(f"refusing to fly: platform {choice.plugin!r} offers no pre-flight check")
    platform = cls()
    with tempfile.TemporaryDirectory(prefix="amslam-preflight-") as tmp:
        context = RunContext(
            rng=np.random.default_rng(mission.model.seed),
            run_dir=Path(tmp),
            robot=mission.model.robot.spec(),
            mission_dir=mission.directory,
        )
        try:
            platform.configure(choice.params, context)
            checks = platform.connect_and_check()
        finally:
            platform.close()
    for check in checks:
        print(f"  {'ok' if check.ok else 'FAIL':<5} {check.name}: {check.detail}")
    failed = [c for c in checks if not c.ok]
    if failed:
        raise AmslamError("refusing to fly: " + "; ".join(f"{c.name}: {c.detail}" for c in failed))
    print("pre-flight check passed", flush=True)
    return cmd_run(args, registry)


def cmd_validate(args, registry) -> int:
    mission, _ = load_with_registry(args, registry)
    plugins = ", ".join(f"{kind}={choice.plugin}" for kind, choice in mission.backends.items())
    print(f"{mission.source}: valid ({plugins})")
    return 0


def cmd_plugins(args, registry) -> int:
    from amslam.hookspecs import since

    for kind, names in registry.backends.items():
        print(f"{kind}:")
        for name in sorted(names):
            plugin = registry.providers[kind][name]
            dist = registry.distributions.get(plugin, "registered in-process")
            print(f"  {name:<12} plugin {plugin!r} from {dist}")
        if not names:
            print("  (none)")
    print("behaviours:")
    print("  " + ", ".join(sorted(registry.behaviours)))
    print("plugins and the hooks they implement (since version):")
    for name, plugin in sorted((n, p) for n, p in registry.pm.list_name_plugin() if p is not None):
        hooks = sorted(c.name for c in registry.pm.get_hookcallers(plugin) or [])
        listed = ", ".join(f"{h} ({since(h)})" for h in hooks) or "(none)"
        print(f"  {name:<16} {registry.distributions.get(name, 'registered in-process')}: {listed}")
    if registry.load_errors:
        print("failed to load (left out):")
        for name in sorted(registry.load_errors):
            print(f"  {registry.load_errors[name]}")
    return 1 if registry.load_errors else 0


def cmd_dump_config(args, registry) -> int:

    cls = registry.backend_class(args.kind, args.plugin)
    print(f"# {args.kind} backend {args.plugin!r} ({cls.__module__}.{cls.__qualname__})")
    doc = (cls.__doc__ or "").strip().splitlines()
    if doc:
        print(f"# {doc[0]}")
    print(f"{args.kind}:")
    print(f"  plugin: {args.plugin}")
    for line in _describe_params(cls.Params, cls.Params().model_dump(mode="json"), indent="  "):
        print(line)
    return 0


def _describe_params(model, values: dict, indent: str) -> list[str]:
    """A parameter model as commented YAML, nested sections as nested blocks."""
    import yaml
    from pydantic import BaseModel

    lines = []
    for name, info in model.model_fields.items():
        if info.description:
            lines.append(f"{indent}# {info.description}")
        sub = info.annotation
        if isinstance(sub, type) and issubclass(sub, BaseModel) and isinstance(values[name], dict):
            lines.append(f"{indent}{name}:")
            lines += _describe_params(sub, values[name], indent + "  ")
            continue
        text = yaml.safe_dump({name: values[name]}, default_flow_style=True, sort_keys=False, width=1000)
        lines.append(f"{indent}{text.strip()[1:-1]}")
    return lines


def cmd_tree(args, registry) -> int:
    import py_trees

    mission, registry = load_with_registry(args, registry)
    real = not registry.backend_class("platform", mission.backends["platform"].plugin).simulated
    root = registry.tree(mission.model.tree)(mission.model, registry.behaviours, failsafe=real)
    if args.format in ("ascii", "unicode"):
        render = py_trees.display.ascii_tree if args.format == "ascii" else py_trees.display.unicode_tree
        return _write_text(render(root), args.out)
    graph = py_trees.display.dot_tree(root, with_blackboard_variables=args.blackboard)
    graph.set_name(mission.name)
    for defaults in (d for kind in ("graph", "node", "edge") for d in graph.get_node(kind)):
        defaults.set("fontname", "DejaVu Sans")  # py_trees' times-roman lacks the Ⓜ of memory composites
    if args.format == "dot":
        return _write_text(graph.to_string(), args.out)
    import shutil
    import subprocess

    if args.format == "png":  # few fonts draw py_trees' Ⓜ (memory composites): spell it for the bitmap
        for node in graph.get_nodes():
            label = node.get("label")
            if label and "Ⓜ " in label:
                node.set("label", label.replace("Ⓜ ", "[M] "))
    dot = shutil.which("dot")
    if dot is None:
        raise AmslamError(
            f"--format {args.format} needs Graphviz's `dot` program: install the Debian package graphviz "
            "(sudo apt-get install -y graphviz); --format ascii and dot work without it"
        )
    out = Path(args.out or f"{mission.name}-tree.{args.format}")
    done = subprocess.run(
        [dot, f"-T{args.format}", "-o", str(out)], input=graph.to_string().encode(), capture_output=True
    )
    if done.returncode != 0:
        raise AmslamError(f"dot failed: {done.stderr.decode(errors='replace').strip()}")
    print(f"tree of {mission.name!r} written to {out}")
    return 0


def _write_text(text: str, out: str | None) -> int:
    if out is None:
        print(text)
    else:
        from amslam.rundir import write_output

        write_output(Path(out), text + "\n")
        print(f"written to {out}")
    return 0


#: the port of ``amslam view --serve`` without ``--port``
DEFAULT_PORT = 8765
#: the three ways of ``amslam view`` and the options each uses (an option of another is refused)
VIEW_MODES = {
    "--at": ("prints the tree's state at a time and writes no page", ()),
    "--serve": ("serves the page live and writes none", ("--port",)),
    "--rerun": ("replays the run into rerun and writes no page", ("--rrd", "--web")),
    "": ("", ("--out", "--screenshot", "--time")),
}
#: an option that needs another
VIEW_NEEDS = {"--time": "--screenshot", "--port": "--serve", "--rrd": "--rerun", "--web": "--rerun"}


def _check_view_options(args) -> None:
    """Refuse an option the chosen mode would silently ignore: one line naming it and its mode."""
    given = {
        "--out": args.out is not None,
        "--screenshot": args.screenshot is not None,
        "--time": args.time is not None,
        "--port": args.port is not None,
        "--serve": args.serve,
        "--rerun": args.rerun,
        "--rrd": args.rrd is not None,
        "--web": args.web,
    }
    mode = "--at" if args.at is not None else "--serve" if args.serve else "--rerun" if args.rerun else ""
    what, uses = VIEW_MODES[mode]
    for option, is_given in given.items():
        if not is_given or option == mode:
            continue
        if option not in uses and mode:
            raise AmslamError(f"{option} does not go with {mode}, which {what}")
        need = VIEW_NEEDS.get(option)
        if need is not None and need != mode and not given[need]:
            raise AmslamError(f"{option} needs {need}")
    if given["--rrd"] and given["--web"]:
        raise AmslamError("--rrd does not go with --web, which serves the recording and saves none")


def cmd_view(args, registry) -> int:
    from amslam.apps.viewer import LiveServer, build_page, resolve_run_folder

    _check_view_options(args)
    run_dir, picked = resolve_run_folder(Path(args.run))
    if picked:
        print(f"newest run in {args.run}: {run_dir}")
    if args.at is not None:
        from amslam.apps.viewer.runfiles import poll_run
        from amslam.apps.viewer.timeline import render_text, tree_state_at

        delta = poll_run(run_dir)
        print(render_text(delta.structure or [], tree_state_at(delta.tree, args.at)))
        return 0
    if args.rerun:
        return _view_rerun(run_dir, args)
    if not args.serve:
        page = build_page(run_dir, Path(args.out) if args.out else None)
        print(f"replay page: {page}")
        if args.screenshot:
            from amslam.apps.viewer.browser import screenshot

            print(f"screenshot: {screenshot(page, Path(args.screenshot), at=args.time)}")
        return 0
    server = LiveServer(run_dir, port=DEFAULT_PORT if args.port is None else args.port)
    print(f"serving {run_dir} at {server.start()} (follows the run while it is written; Ctrl-C to stop)")
    try:
        server.thread.join()
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
    return 0


def _view_rerun(run_dir: Path, args) -> int:
    """``amslam view RUN --rerun``: the run replayed into a rerun recording (see docs/viewer.md)."""
    import time

    from amslam.apps.rerun_view import open_recording, replay_run

    rec, where = open_recording(run_dir, args.rrd, args.web)
    counts = replay_run(run_dir, rec)
    rec.flush()
    shapes = counts["landmarks_cuboid"] + counts["landmarks_cylinder"]
    print(
        f"replayed {run_dir} into rerun: {counts['events']} events, {counts['tree']} tree changes, "
        f"poses {counts['ground_truth']} true / {counts['vio']} VIO / {counts['slam']} SLAM, "
        f"{counts['map']} map voxels, {shapes + counts['landmarks_point']} landmarks ({shapes} with a shape)"
    )
    print(where, flush=True)
    if args.web:  # the web viewer lives as long as this process
        try:
            while True:
                time.sleep(3600)
        except KeyboardInterrupt:
            pass
    return 0


def _mission_arguments(
    parser, what: str = "mission file, or the name of a packaged mission (e.g. demo)"
) -> None:
    parser.add_argument("mission", help=what)
    parser.add_argument("--set", action="append", metavar="KEY.PATH=VALUE", help="override a mission value")


def _flight_arguments(parser) -> None:
    _mission_arguments(parser)
    parser.add_argument("--out", default="runs", help="folder that receives the run folder (default: runs)")
    _rerun_arguments(parser, "stream the flight live into rerun (pip install 'amslam[interop]')")


def _rerun_arguments(parser, what: str) -> None:
    parser.add_argument("--rerun", action="store_true", help=what)
    parser.add_argument(
        "--rrd",
        nargs="?",
        const="",
        metavar="FILE",
        help="with --rerun: save the recording instead of spawning rerun's viewer (FILE, default "
        "RUN/recording.rrd; the default anyway when there is no display)",
    )


def _dump_config_arguments(parser) -> None:
    parser.add_argument("kind", help="platform, mapping, slam, detector or planner")
    parser.add_argument("plugin", help="backend name, as listed by `amslam plugins`")


def _tree_arguments(parser) -> None:
    _mission_arguments(parser)
    parser.add_argument(
        "--format",
        choices=["ascii", "unicode", "dot", "svg", "png"],
        default="ascii",
        help="text (ascii, unicode), Graphviz source (dot) or a drawing (svg, png: needs Graphviz)",
    )
    parser.add_argument("--out", help="file to write (svg/png default: MISSION-tree.FORMAT; text: stdout)")
    parser.add_argument("--blackboard", action="store_true", help="dot/svg/png: show the blackboard keys")


def _view_arguments(parser) -> None:
    parser.add_argument("run", help="a run folder, or a folder of runs (the newest is shown)")
    parser.add_argument("--out", help="page to write (default: RUN/viewer.html)")
    parser.add_argument(
        "--serve", action="store_true", help="serve on 127.0.0.1 and follow a run in progress"
    )
    parser.add_argument(
        "--port",
        type=whole_number(0, 65535),
        help=f"port for --serve (default {DEFAULT_PORT}; 0: any free)",
    )
    parser.add_argument("--at", type=float, metavar="T", help="print the tree's state at time T (s) instead")
    parser.add_argument(
        "--screenshot", metavar="PNG", help="also save a picture of the page (headless Chromium)"
    )
    parser.add_argument(
        "--time", type=float, metavar="T", help="the page's initial time (s), for --screenshot"
    )
    _rerun_arguments(parser, "replay the run in rerun's 3-D viewer instead (pip install 'amslam[interop]')")
    parser.add_argument(
        "--web",
        action="store_true",
        help="with --rerun: serve rerun's web viewer on localhost (Ctrl-C to stop)",
    )


@amslam.hookimpl
def amslam_cli_commands():
    return {
        "run": Command("fly a mission and write a run folder", _flight_arguments, cmd_run),
        "fly": Command(
            "fly a mission on a real vehicle, after a pre-flight check", _flight_arguments, cmd_fly
        ),
        "validate": Command("check a mission without flying it", _mission_arguments, cmd_validate),
        "plugins": Command(
            "list installed backends by kind and who provides them", lambda parser: None, cmd_plugins
        ),
        "dump-config": Command(
            "print a backend's parameters with defaults and docs", _dump_config_arguments, cmd_dump_config
        ),
        "tree": Command("print or draw the behaviour tree a mission would run", _tree_arguments, cmd_tree),
        "view": Command(
            "replay a run folder in the browser (tree, map, trajectories, events) or in rerun",
            _view_arguments,
            cmd_view,
        ),
    }
