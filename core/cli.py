"""The ``amslam`` command line.

    amslam run MISSION [--out DIR] [--set key.path=value ...]
    amslam fly MISSION [--out DIR] [--set key.path=value ...]   (a real vehicle, after a pre-flight check)
    amslam validate MISSION
    amslam plugins
    amslam dump-config KIND PLUGIN
    amslam tree MISSION [--format ascii|unicode|dot|svg|png] [--out FILE]
    amslam view RUN_DIR [--out FILE] [--screenshot PNG [--time T]] [--serve [--port N]] [--at T]
    amslam experiment {slc-ablation,planners} MISSION [--seeds N]
    amslam experiment pams MISSION [MISSION ...] [--seeds N]
    amslam characterise [MISSION] --out MODELS.npz [--poses N] [--seed S]
    amslam experiment multi-robot MISSION [--robots 1,2,3] [--mode homogeneous|heterogeneous|both] [--seeds N]
        [--reuse DIR] [--odometry vio|slam]

MISSION is a YAML file or the name of a packaged mission (``demo``). Errors amslam can explain
are printed as ``error: ...`` lines with exit status 2, never as a traceback.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from amslam.errors import AmslamError, MissionError


def _registry(disabled=()):
    from amslam.registry import build_plugin_manager

    return build_plugin_manager(disabled)


def _load(args):
    """Build the registry honouring the mission's ``plugins.disable``, then validate the mission."""
    import yaml

    from amslam.mission import load_mission, resolve_mission_path

    disabled: list[str] = []
    try:
        raw = yaml.safe_load(resolve_mission_path(args.mission).read_text()) or {}
        section = raw.get("plugins") if isinstance(raw, dict) else None
        if isinstance(section, dict) and isinstance(section.get("disable"), list):
            disabled = [str(x) for x in section["disable"]]
    except yaml.YAMLError:
        pass  # load_mission reports it with the line
    registry = _registry(disabled)
    mission = load_mission(args.mission, registry, getattr(args, "set", None) or [])
    for name in mission.model.plugins.optional:  # load_mission refused every other load error
        if name in registry.load_errors:
            print(f"warning: optional {registry.load_errors[name]}; going on without it", file=sys.stderr)
    return mission, registry


def cmd_run(args) -> int:
    from amslam.runner import Runner

    mission, registry = _load(args)
    print(f"flying mission {mission.name!r} ({mission.source})", flush=True)

    def announce(run_dir: Path) -> None:
        print(f"run folder: {run_dir}  (watch it live: amslam view {run_dir} --serve)", flush=True)

    progress = not args.quiet and sys.stderr.isatty()  # a bar in a log file is noise
    result = Runner(mission, registry, Path(args.out), progress=progress, on_start=announce).run()
    m = result.metrics
    print(f"verdict: {result.verdict}")
    if "explored_percent" in m:
        share, distance = m["explored_percent"], m.get("distance_m")
        print(f"explored: {share} % of the reachable free volume, distance {distance} m")
    print(f"run folder: {result.run_dir}")
    print(f"report: {result.report}")
    return 0 if result.verdict == "completed" else 1


def cmd_fly(args) -> int:
    """Fly a real vehicle: the pre-flight check first, refusing with every reason that failed."""
    import tempfile

    import numpy as np

    from amslam.interfaces import RunContext

    mission, registry = _load(args)
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
    return cmd_run(args)


def cmd_validate(args) -> int:
    mission, _ = _load(args)
    plugins = ", ".join(f"{kind}={choice.plugin}" for kind, choice in mission.backends.items())
    print(f"{mission.source}: valid ({plugins})")
    return 0


def cmd_plugins(args) -> int:
    from amslam.hookspecs import since

    registry = _registry()
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


def cmd_dump_config(args) -> int:

    registry = _registry()
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


def cmd_tree(args) -> int:
    import py_trees

    from amslam.trees.flight import build_mission_tree

    mission, registry = _load(args)
    real = not registry.backend_class("platform", mission.backends["platform"].plugin).simulated
    root = build_mission_tree(mission.model, registry.behaviours, failsafe=real)
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
        Path(out).write_text(text + "\n")
        print(f"written to {out}")
    return 0


def cmd_view(args) -> int:
    from amslam.viewer import LiveServer, build_page, resolve_run_folder

    run_dir, picked = resolve_run_folder(Path(args.run))
    if picked:
        print(f"newest run in {args.run}: {run_dir}")
    if args.at is not None:
        from amslam.viewer.runfiles import poll_run
        from amslam.viewer.timeline import render_text, tree_state_at

        delta = poll_run(run_dir)
        print(render_text(delta.structure or [], tree_state_at(delta.tree, args.at)))
        return 0
    if not args.serve:
        page = build_page(run_dir, Path(args.out) if args.out else None)
        print(f"replay page: {page}")
        if args.screenshot:
            from amslam.viewer.browser import screenshot

            print(f"screenshot: {screenshot(page, Path(args.screenshot), at=args.time)}")
        return 0
    server = LiveServer(run_dir, port=args.port)
    print(f"serving {run_dir} at {server.start()} (follows the run while it is written; Ctrl-C to stop)")
    try:
        server.thread.join()
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
    return 0


def cmd_experiment(args) -> int:
    from amslam import experiments

    registry = _registry()
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    print(f"experiment {args.name} on {args.mission}, seeds {seeds}", flush=True)
    if args.name == "slc-ablation":
        folder = experiments.slc_ablation(args.mission, registry, seeds, Path(args.out), args.set or [])
    elif args.name == "pams":
        missions = [args.mission, *args.more]
        folder = experiments.pams_comparison(
            missions, registry, seeds, Path(args.out), overrides=args.set or []
        )
    elif args.name == "multi-robot":
        from amslam import multirobot

        robots = [int(n) for n in args.robots.split(",")]
        folder = multirobot.multi_robot(
            args.mission,
            registry,
            seeds,
            Path(args.out),
            robots,
            args.mode,
            args.set or [],
            args.schedule,
            reuse=[Path(d) for d in args.reuse or []],
            odometry=args.odometry,
        )
    else:
        folder = experiments.planner_comparison(
            args.mission, registry, seeds, Path(args.out), overrides=args.set or []
        )
    print((folder / "table.md").read_text())
    print(f"experiment folder: {folder}")
    return 0


def cmd_characterise(args) -> int:
    from amslam.plugins.pams.uncertainty import characterise

    mission = _load(args)[0] if args.mission else None
    characterise(Path(args.out), mission=mission, poses_per_spiral=args.poses, seed=args.seed)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="amslam", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="fly a mission and write a run folder")
    run.add_argument("mission", help="mission file, or the name of a packaged mission (e.g. demo)")
    run.add_argument("--out", default="runs", help="folder that receives the run folder (default: runs)")
    run.add_argument("--set", action="append", metavar="KEY.PATH=VALUE", help="override a mission value")
    run.add_argument("--quiet", action="store_true", help="no progress bar")
    run.set_defaults(func=cmd_run)
    fly = sub.add_parser("fly", help="fly a mission on a real vehicle, after a pre-flight check")
    fly.add_argument("mission", help="mission file, or the name of a packaged mission (e.g. px4_square)")
    fly.add_argument("--out", default="runs", help="folder that receives the run folder (default: runs)")
    fly.add_argument("--set", action="append", metavar="KEY.PATH=VALUE", help="override a mission value")
    fly.add_argument("--quiet", action="store_true", help="no progress bar")
    fly.set_defaults(func=cmd_fly)
    val = sub.add_parser("validate", help="check a mission without flying it")
    val.add_argument("mission")
    val.add_argument("--set", action="append", metavar="KEY.PATH=VALUE")
    val.set_defaults(func=cmd_validate)
    plg = sub.add_parser("plugins", help="list installed backends by kind and who provides them")
    plg.set_defaults(func=cmd_plugins)
    dump = sub.add_parser("dump-config", help="print a backend's parameters with defaults and docs")
    dump.add_argument("kind", help="platform, mapping, slam, detector or planner")
    dump.add_argument("plugin", help="backend name, as listed by `amslam plugins`")
    dump.set_defaults(func=cmd_dump_config)
    tree = sub.add_parser("tree", help="print or draw the behaviour tree a mission would run")
    tree.add_argument("mission")
    tree.add_argument(
        "--format",
        choices=["ascii", "unicode", "dot", "svg", "png"],
        default="ascii",
        help="text (ascii, unicode), Graphviz source (dot) or a drawing (svg, png: needs Graphviz)",
    )
    tree.add_argument("--out", help="file to write (svg/png default: MISSION-tree.FORMAT; text: stdout)")
    tree.add_argument("--blackboard", action="store_true", help="dot/svg/png: show the blackboard keys")
    tree.add_argument("--set", action="append", metavar="KEY.PATH=VALUE", help="override a mission value")
    tree.set_defaults(func=cmd_tree)
    view = sub.add_parser("view", help="replay a run folder in the browser: tree, map, trajectories, events")
    view.add_argument("run", help="a run folder, or a folder of runs (the newest is shown)")
    view.add_argument("--out", help="page to write (default: RUN/viewer.html)")
    view.add_argument("--serve", action="store_true", help="serve on 127.0.0.1 and follow a run in progress")
    view.add_argument("--port", type=int, default=8765, help="port for --serve (default 8765; 0: any free)")
    view.add_argument("--at", type=float, metavar="T", help="print the tree's state at time T (s) instead")
    view.add_argument(
        "--screenshot", metavar="PNG", help="also save a picture of the page (headless Chromium)"
    )
    view.add_argument("--time", type=float, metavar="T", help="the page's initial time (s), for --screenshot")
    view.set_defaults(func=cmd_view)
    char = sub.add_parser("characterise", help="fit confidence and geometric-error models (paper 2 §IV-C)")
    char.add_argument("mission", nargs="?", help="mission whose simulated camera and detector to use")
    char.add_argument("--out", required=True, help="models file to write (.npz; samples and plot beside it)")
    char.add_argument("--poses", type=int, help="frames per spiral (default 240)")
    char.add_argument("--seed", type=int, default=0)
    char.set_defaults(func=cmd_characterise)
    exp = sub.add_parser("experiment", help="fly a mission several ways over several seeds and compare")
    exp.add_argument(
        "name", choices=["slc-ablation", "planners", "multi-robot", "pams"], help="which comparison"
    )
    exp.add_argument("mission")
    exp.add_argument("more", nargs="*", help="pams: further missions (one world each)")
    exp.add_argument("--seeds", type=int, default=5, help="number of seeds (default 5)")
    exp.add_argument("--first-seed", type=int, default=1)
    exp.add_argument("--out", default="runs", help="folder that receives the experiment folder")
    exp.add_argument("--set", action="append", metavar="KEY.PATH=VALUE", help="override for every run")
    exp.add_argument("--robots", default="1,2,3", help="multi-robot: team sizes (default 1,2,3)")
    exp.add_argument(
        "--mode",
        choices=["homogeneous", "heterogeneous", "both"],
        default="homogeneous",
        help="multi-robot: same robots on split areas, low-altitude robots + an overhead robot, or both",
    )
    exp.add_argument(
        "--schedule",
        choices=["simultaneous", "sequential"],
        default="simultaneous",
        help="multi-robot: team time = longest robot's (simultaneous) or the sum (sequential)",
    )
    exp.add_argument(
        "--reuse",
        action="append",
        metavar="DIR",
        help="multi-robot: reuse robot runs under DIR (earlier experiments) that fly the same flight",
    )
    exp.add_argument(
        "--odometry",
        choices=["vio", "slam"],
        default="vio",
        help="multi-robot: chain each robot's key poses with its VIO (default) or its onboard SLAM estimate",
    )
    exp.set_defaults(func=cmd_experiment)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except MissionError as exc:
        for problem in exc.problems:
            print(f"error: {problem}", file=sys.stderr)
        return 2
    except AmslamError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
