"""The commands that only read (list plugins, validate a mission, draw its tree, show a backend's
parameters, help) import none of the heavy libraries the backends fly with (issue #20): those are
imported when a backend is built. Each check runs in a fresh interpreter, where ``sys.modules``
shows exactly what the commands imported."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

#: imported by a backend when it is built (or by an application when it runs), never to read
HEAVY = (
    "open3d",
    "gtsam",
    "scipy",
    "numba",
    "sklearn",
    "onnxruntime",
    "cv2",
    "mavsdk",
    "pymavlink",
    "matplotlib",
    "plyfile",
    "trimesh",
    "collada",
    "rerun",
    "mcap",
    "mcap_ros2",
    "rosbags",
    "pyoctomap",
    "torch",
    "tqdm",
    "threadpoolctl",
)

#: what a user types to look before flying; each runs in the same interpreter, one after the other
COMMANDS = (
    ["--help"],
    ["plugins"],
    ["validate", "demo"],
    ["tree", "demo"],
    ["missions"],
    ["dump-config", "slam", "gtsam"],
    ["dump-config", "mapping", "open3d"],
    ["dump-config", "platform", "mavsdk"],
    ["dump-config", "detector", "onnx"],
    ["dump-config", "planner", "pams"],
)


def run_commands(block_heavy: bool) -> dict:
    """Run :data:`COMMANDS` through ``amslam.cli.main`` in a fresh interpreter; return each exit
    status, what each printed, and which :data:`HEAVY` libraries were imported at the end.

    ``block_heavy``: make importing any of them fail, as on a machine without them."""
    script = textwrap.dedent(
        """\
        import contextlib, io, json, sys

        heavy, commands, block = json.loads(sys.argv[1])
        if block:
            for name in heavy:
                sys.modules[name] = None  # `import name` raises ImportError
        from amslam.cli import main

        results = []
        for argv in commands:
            out, err = io.StringIO(), io.StringIO()
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                try:
                    status = main(argv)
                except SystemExit as exc:  # --help
                    status = exc.code
            results.append({"argv": argv, "status": status, "out": out.getvalue(), "err": err.getvalue()})
        imported = sorted(n for n in heavy if sys.modules.get(n) is not None)
        print(json.dumps({"results": results, "imported": imported}))
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", script, json.dumps([HEAVY, COMMANDS, block_heavy])],
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(done.stdout)


def test_reading_commands_import_no_heavy_library():
    found = run_commands(block_heavy=False)
    for result in found["results"]:
        assert result["status"] == 0, result
    assert found["imported"] == []


def test_reading_commands_work_without_the_heavy_libraries():
    """Every plugin loads and every parameter model validates with the heavy libraries missing:
    the models and the plugins' modules need none of them. Validating a mission still names what
    its backends will import and is not installed (``Backend.requires``), one line each (so does
    drawing its tree, which loads it)."""
    found = run_commands(block_heavy=True)
    for result in found["results"]:
        assert "failed to load" not in result["out"] + result["err"], result
        if result["argv"][0] not in ("validate", "tree"):  # the two that load a mission
            assert result["status"] == 0, result
    validate = next(r for r in found["results"] if r["argv"][0] == "validate")
    assert validate["status"] == 2 and "Traceback" not in validate["err"]
    lines = validate["err"].strip().splitlines()
    assert [line.split(": ")[2] for line in lines] == ["platform.plugin", "mapping.plugin", "slam.plugin"]
    needs = "slam.plugin: 'gtsam' needs the Python modules 'gtsam', 'sklearn', not installed here"
    assert lines[2].endswith(needs)


#: the modules the built-in plugins name with ``amslam.deferred.Deferred``: each is imported when its
#: backend, behaviour or tree is first used, not when the registry is built (issue #20)
BACKEND_MODULES = {
    ("platform", "sim"): "amslam.plugins.sim.platform",
    ("platform", "mavsdk"): "amslam.plugins.mavsdk_platform.platform",
    ("mapping", "open3d"): "amslam.plugins.voxel_open3d.backend",
    ("mapping", "numpy"): "amslam.plugins.voxel_numpy.backend",
    ("slam", "gtsam"): "amslam.plugins.gtsam_slam.backend",
    ("detector", "sim"): "amslam.plugins.sim.detector",
    ("detector", "onnx"): "amslam.plugins.onnx_detector.detector",
    ("planner", "cop"): "amslam.plugins.planners.cop",
    ("planner", "greedy"): "amslam.plugins.planners.greedy",
    ("planner", "tsp"): "amslam.plugins.planners.tsp",
    ("planner", "pams"): "amslam.plugins.pams.planner",
}
TREE_MODULES = (
    "amslam.trees.behaviours",
    "amslam.trees.decorators",
    "amslam.trees.flight",
    "amslam.trees.exploration",
)


def modules_after(argv: list[str]) -> set[str]:
    """The modules a fresh interpreter holds after running ``amslam ARGV`` (exit status 0)."""
    script = textwrap.dedent(
        """\
        import contextlib, io, json, sys
        from amslam.cli import main

        with contextlib.redirect_stdout(io.StringIO()):
            try:
                status = main(json.loads(sys.argv[1]))
            except SystemExit as exc:  # --help
                status = exc.code
        print(json.dumps({"status": status, "modules": sorted(sys.modules)}))
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", script, json.dumps(argv)], capture_output=True, text=True, check=True
    )
    found = json.loads(done.stdout)
    assert found["status"] == 0, done.stderr
    return set(found["modules"])


def test_listing_imports_no_backend_tree_mission_or_yaml():
    """``amslam plugins`` and ``--help`` read names: no backend's module, no behaviour tree (nor
    py_trees), no mission models, no YAML parser."""
    for argv in (["plugins"], ["--help"]):
        modules = modules_after(argv)
        unwanted = {*BACKEND_MODULES.values(), *TREE_MODULES, "py_trees", "amslam.mission", "yaml"}
        assert not modules & unwanted, (argv, sorted(modules & unwanted))


def test_validating_imports_only_the_backends_the_mission_names():
    """``amslam validate demo`` imports the modules of the five backends demo.yaml names (their
    parameter models validate it) and no other backend's, and draws no tree (no py_trees)."""
    modules = modules_after(["validate", "demo"])
    named = {
        ("platform", "sim"),
        ("mapping", "open3d"),
        ("slam", "gtsam"),
        ("detector", "sim"),
        ("planner", "cop"),
    }
    assert {BACKEND_MODULES[b] for b in named} <= modules
    others = {module for backend, module in BACKEND_MODULES.items() if backend not in named}
    assert not modules & others, sorted(modules & others)
    assert not modules & {*TREE_MODULES, "py_trees"}, sorted(modules & {*TREE_MODULES, "py_trees"})


def test_drawing_a_tree_imports_its_behaviours():
    """The deferred behaviours and tree builder are imported when ``amslam tree`` builds the tree."""
    modules = modules_after(["tree", "demo"])
    assert {
        "py_trees",
        "amslam.trees.behaviours",
        "amslam.trees.exploration",
        "amslam.trees.flight",
    } <= modules
