"""``amslam world``: bring other people's buildings into the simulator.

``amslam world import SOURCE --out DIR`` turns a Gazebo world (``.world``/``.sdf``) or a plain mesh
(``.obj``, ``.glb``, ``.dae``, ``.ply``, ...) into the mesh world the simulator flies
(:mod:`.importer`); ``amslam world class-map`` prints the default class map to edit.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import amslam
from amslam.cli import Command


def _arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="world_command", required=True, metavar="ACTION")
    help_ = "a Gazebo world or a mesh file → a mesh world (world.ply, objects.json) and a mission"
    one = sub.add_parser("import", help=help_, description=help_)
    one.add_argument(
        "source", help="world file (.world, .sdf) or mesh file (.obj, .glb, .gltf, .dae, .ply, .stl)"
    )
    one.add_argument(
        "--out", required=True, help="folder to write world.ply, objects/, objects.json, mission.yaml"
    )
    one.add_argument(
        "--class-map",
        metavar="FILE",
        help="YAML of model-name patterns → amslam class (default: the packaged one, see `world class-map`)",
    )
    one.add_argument(
        "--model-path",
        metavar="DIR",
        nargs="+",
        action="extend",
        default=[],
        help="folders of Gazebo models, searched for model:// before GAZEBO_MODEL_PATH, GZ_SIM_RESOURCE_PATH",
    )
    one.add_argument(
        "--geometry",
        choices=["visual", "collision"],
        default="visual",
        help="import the links' <visual>s (what the camera sees; default) or <collision>s",
    )
    one.add_argument(
        "--skip-missing",
        action="store_true",
        help="skip includes and meshes that cannot be found (listed in the summary) instead of stopping",
    )
    one.add_argument(
        "--up-axis",
        choices=["auto", "x", "y", "z"],
        default="auto",
        help="plain meshes: the file's up axis (auto: COLLADA's <up_axis>, y for glTF, z otherwise)",
    )
    one.add_argument(
        "--scale", type=float, default=1.0, help="plain meshes: metres per file unit (default 1)"
    )
    one.add_argument(
        "--plane-margin",
        type=float,
        default=1.0,
        help="horizontal <plane>s are cut to the rest of the world plus this margin, m (default 1)",
    )
    one.add_argument("--name", help="world and mission name (default: the <world> name or the file name)")
    sub.add_parser("class-map", help="print the default class map (edit it and pass --class-map)")


def _run(args: argparse.Namespace, registry) -> int:
    from amslam.apps.worlds.classmap import default_map_text

    if args.world_command == "class-map":
        print(default_map_text(), end="")
        return 0
    from amslam.apps.worlds.importer import ImportOptions, import_world, summary_text
    from amslam.apps.worlds.sdf import WorldImportError

    if args.scale <= 0:
        raise WorldImportError(f"--scale must be positive, got {args.scale}")
    model_path = [Path(p) for entry in args.model_path for p in entry.split(os.pathsep) if p]
    options = ImportOptions(
        class_map=Path(args.class_map) if args.class_map else None,
        model_path=model_path,
        geometry=args.geometry,
        skip_missing=args.skip_missing,
        up_axis=args.up_axis,
        scale=args.scale,
        plane_margin=args.plane_margin,
        name=args.name,
    )
    result = import_world(Path(args.source), Path(args.out), options)
    print(summary_text(result))
    return 0


@amslam.hookimpl
def amslam_cli_commands():
    return {"world": Command("import Gazebo worlds and meshes as simulator worlds", _arguments, _run)}
