"""Backends that raise or hand the runtime garbage: the run ends ``failed`` with a verdict naming
kind, plugin and distribution, and its run folder is complete and parses (no traceback escapes,
no NaN reaches ``measurements.jsonl``). Short flights in-process: ``limits.max_time`` 40 s."""

from __future__ import annotations

import dataclasses
import json
import re

import numpy as np
import pytest

import amslam
from amslam.boundary import Boundary
from amslam.mission import load_mission
from amslam.plugins.odometry_slam import OdometrySlam
from amslam.plugins.planners.greedy import GreedyPlanner
from amslam.plugins.sim.detector import SimDetector
from amslam.plugins.sim.platform import SimPlatform
from amslam.plugins.voxel_open3d.backend import Open3dVoxelMap
from amslam.registry import build_plugin_manager
from amslam.runner import Runner
from amslam.types import Detection, Frame, Odometry, TourItem, TourItemKind, Viewpoint
from tests.e2e.missions import small_mission

IN_PROCESS = "(registered in-process, from no distribution)"


# -- broken backends -----------------------------------------------------------------------------


class NanOdometry(SimPlatform):
    """VIO that diverges to NaN after two seconds."""

    def odometry(self) -> Odometry:
        odom = super().odometry()
        if self.time() > 2.0:
            T = odom.T_odom_body.copy()
            T[0, 3] = np.nan
            return Odometry(odom.stamp, T)
        return odom


class SkewedOdometry(SimPlatform):
    def odometry(self) -> Odometry:
        odom = super().odometry()
        if self.time() > 2.0:
            T = odom.T_odom_body.copy()
            T[:3, :3] *= 2.0
            return Odometry(odom.stamp, T)
        return odom


class TupleOdometry(SimPlatform):
    def odometry(self):
        odom = super().odometry()
        return (odom.stamp, odom.T_odom_body) if self.time() > 2.0 else odom


class FlatDepth(SimPlatform):
    def capture(self) -> Frame | None:
        frame = super().capture()
        if frame is not None and self.time() > 2.0:
            return dataclasses.replace(frame, depth=frame.depth.ravel())
        return frame


class NanDetector(SimDetector):
    def detect(self, frame):
        return [Detection("chair", 0.9, np.array([np.nan, 0.0, 2.0]))]


class DictDetector(SimDetector):
    def detect(self, frame):
        return {"chair": 0.9}


class StringDetector(SimDetector):
    def detect(self, frame):
        return [Detection("chair", 0.9, np.zeros(3)), "chair"]


class OverconfidentDetector(SimDetector):
    def detect(self, frame):
        return [Detection("chair", 7.0, np.array([0.0, 0.0, 2.0]))]


class RaisingDetector(SimDetector):
    def detect(self, frame):
        raise IndexError("list index out of range")


class NanSlam(OdometrySlam):
    def T_world_odom(self) -> np.ndarray:
        T = np.eye(4)
        T[2, 3] = np.inf
        return T


class RaisingPlanner(GreedyPlanner):
    def plan(self, request):
        raise RuntimeError("solver diverged")


class StrangerPlanner(GreedyPlanner):
    """Tours a viewpoint it was never offered."""

    def plan(self, request):
        return [TourItem(TourItemKind.EXPLORE, np.array([1.0, 1.0, 1.2]), 0.0, 1.0, 987654)]


class SlcStrangerPlanner(GreedyPlanner):
    def plan(self, request):
        return [TourItem(TourItemKind.SLC, np.array([1.0, 1.0, 1.2]), 0.0, 1.0, 4242)]


class NanTourPlanner(GreedyPlanner):
    def plan(self, request):
        tour = super().plan(request)
        return [dataclasses.replace(item, position=np.full(3, np.nan)) for item in tour]


class StringPlanner(GreedyPlanner):
    def plan(self, request):
        return "go north"


class NonePlanner(GreedyPlanner):
    def plan(self, request):
        return None


class DictItemPlanner(GreedyPlanner):
    def plan(self, request):
        return [{"position": [1, 1, 1]}]


class BadViewpoints(Open3dVoxelMap):
    def viewpoints(self):
        return [np.zeros(3)]


class RaisingConfigure(GreedyPlanner):
    def configure(self, params, context):
        raise KeyError("weights")


class RaisingAdvance(SimPlatform):
    def advance(self, dt):
        if self.time() > 2.0:
            raise ZeroDivisionError("float division by zero")
        super().advance(dt)


class NanStamp(SimPlatform):
    def odometry(self) -> Odometry:
        odom = super().odometry()
        return Odometry(float("nan"), odom.T_odom_body) if self.time() > 2.0 else odom


class WideK(SimPlatform):
    def capture(self) -> Frame | None:
        frame = super().capture()
        return None if frame is None else dataclasses.replace(frame, K=np.eye(4))


class RaggedPoints(SimDetector):
    def detect(self, frame):
        return [Detection("chair", 0.5, np.zeros(3), points_cam=np.zeros((5, 2)))]


class NamelessDetector(SimDetector):
    def detect(self, frame):
        return [Detection(None, 0.5, np.zeros(3))]


class RaisingOdometrySlam(OdometrySlam):
    def add_odometry(self, odom):
        raise AttributeError("'NoneType' object has no attribute 'pose'")


class RaisingLocalMap(Open3dVoxelMap):
    def integrate_local(self, depth, K, T_odom_cam):
        raise MemoryError("voxel hash table full")


class NanYawViewpoints(Open3dVoxelMap):
    def viewpoints(self):
        return [Viewpoint(0, np.zeros(3), float("nan"), 1.0, np.zeros(3), 1)]


class FlatTourPlanner(GreedyPlanner):
    def plan(self, request):
        return [dataclasses.replace(item, position=np.zeros(2)) for item in super().plan(request)] or [
            TourItem(TourItemKind.EXPLORE, np.zeros(2), 0.0, 1.0, 0)
        ]


class TextRefPlanner(GreedyPlanner):
    def plan(self, request):
        return [dataclasses.replace(item, ref="first") for item in super().plan(request)] or [
            TourItem(TourItemKind.EXPLORE, np.zeros(3), 0.0, 1.0, "first")
        ]


class Broken:
    @amslam.hookimpl
    def amslam_platform_backends(self):
        return {"nan_odom": NanOdometry, "skewed": SkewedOdometry, "tuple_odom": TupleOdometry,
                "flat_depth": FlatDepth, "raising_advance": RaisingAdvance, "nan_stamp": NanStamp,
                "wide_k": WideK}  # fmt: skip

    @amslam.hookimpl
    def amslam_detector_backends(self):
        return {"nan_det": NanDetector, "dict_det": DictDetector, "str_det": StringDetector,
                "sure_det": OverconfidentDetector, "raising_det": RaisingDetector, "ragged": RaggedPoints,
                "nameless": NamelessDetector}  # fmt: skip

    @amslam.hookimpl
    def amslam_slam_backends(self):
        return {"nan_slam": NanSlam, "raising_slam": RaisingOdometrySlam}

    @amslam.hookimpl
    def amslam_mapping_backends(self):
        return {"bad_vps": BadViewpoints, "raising_local": RaisingLocalMap, "nan_yaw": NanYawViewpoints}

    @amslam.hookimpl
    def amslam_planner_backends(self):
        return {"raising": RaisingPlanner, "stranger": StrangerPlanner, "slc_stranger": SlcStrangerPlanner,
                "nan_tour": NanTourPlanner, "string": StringPlanner, "none": NonePlanner,
                "dict_item": DictItemPlanner, "raising_configure": RaisingConfigure,
                "flat_tour": FlatTourPlanner, "text_ref": TextRefPlanner}  # fmt: skip


def fly(tmp_path, kind: str, plugin: str):
    """The small mission with one backend swapped for a broken one, flown for at most 40 s."""
    path = small_mission(tmp_path, max_time=40)
    text = path.read_text()
    sections = {
        "platform": "  plugin: sim\n",
        "slam": "slam: {plugin: odometry}",
        "detector": "detector: {plugin: sim}",
        "planner": "planner: {plugin: greedy}",
        "mapping": "mapping: {plugin: open3d}",
    }
    old = sections[kind]
    new = old.replace(old.split("plugin: ")[1].rstrip("}\n"), plugin)
    assert old in text
    path.write_text(text.replace(old, new, 1))
    registry = build_plugin_manager(extra_plugins=[Broken()])
    result = Runner(load_mission(path, registry), registry, tmp_path / "runs").run()
    check_run_folder(result)
    return result


def check_run_folder(result) -> None:
    """Every file of the run folder parses; the last event is the verdict; no bare NaN anywhere."""
    run = result.run_dir

    def strict(name: str):
        raise AssertionError(f"bare {name} in a JSON file")

    metrics = json.loads((run / "metrics.json").read_text(), parse_constant=strict)
    assert metrics["verdict"] == result.verdict
    for name in ("events.jsonl", "tree.jsonl", "measurements.jsonl"):
        path = run / name
        if path.exists():
            for line in path.read_text().splitlines():
                json.loads(line, parse_constant=strict)
    events = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    assert events[-1] == {"t": events[-1]["t"], "event": "run_end", "verdict": result.verdict}
    assert (run / "report.md").read_text().count(result.verdict) >= 1


CASES = [
    ("platform", "nan_odom", "odometry(): T_odom_body is not finite (nan at [0, 3])"),
    ("platform", "skewed", "odometry(): T_odom_body has a rotation that is not orthonormal"),
    ("platform", "tuple_odom", "odometry() returned tuple, expected Odometry"),
    ("platform", "flat_depth", "capture(): depth is not a 2-D array of numbers (got ndarray (19200,))"),
    ("detector", "nan_det", "detect(): detection 0: centroid_cam is not finite (nan at [0])"),
    ("detector", "dict_det", "detect() returned dict, expected a list"),
    ("detector", "str_det", "detect(): detection 1: is a str, expected Detection"),
    ("detector", "sure_det", "detect(): detection 0: confidence 7.0 is not a number in [0, 1]"),
    ("detector", "raising_det", "detect() raised IndexError: list index out of range"),
    ("slam", "nan_slam", "T_world_odom(): the pose is not finite (inf at [2, 3])"),
    ("mapping", "bad_vps", "viewpoints(): viewpoint 0: is a ndarray, expected Viewpoint"),
    ("planner", "slc_stranger",
     "plan(): stop 0: SLC stop for key pose 4242, which was not among the request's candidates"),
    ("planner", "nan_tour", "plan(): stop 0: position is NaN (an unreachable stop is +inf)"),
    ("planner", "string", "plan() returned str, expected a list of TourItem"),
    ("planner", "none", "plan() returned NoneType, expected a list of TourItem"),
    ("planner", "dict_item", "plan(): stop 0: is a dict, expected TourItem"),
    ("planner", "raising_configure", "configure() raised KeyError: 'weights'"),
    ("platform", "raising_advance", "advance() raised ZeroDivisionError: float division by zero"),
    ("platform", "nan_stamp", "odometry(): stamp nan is not a finite number"),
    ("platform", "wide_k", "capture(): K has shape (4, 4), expected (3, 3)"),
    ("detector", "ragged", "detect(): detection 0: points_cam has shape (5, 2), expected (N, 3)"),
    ("detector", "nameless", "detect(): detection 0: class_name None is not a name"),
    ("slam", "raising_slam",
     "add_odometry() raised AttributeError: 'NoneType' object has no attribute 'pose'"),
    ("mapping", "raising_local", "integrate_local() raised MemoryError: voxel hash table full"),
    ("mapping", "nan_yaw", "viewpoints(): viewpoint 0: yaw nan or gain 1.0 is not a finite number"),
    ("planner", "flat_tour", "plan(): stop 0: position has shape (2,), expected (3,)"),
    ("planner", "text_ref", "plan(): stop 0: ref 'first' is not an integer id"),
]  # fmt: skip


@pytest.mark.parametrize(("kind", "plugin", "what"), CASES, ids=[c[1] for c in CASES])
def test_a_broken_backend_fails_the_run_naming_it(tmp_path, kind, plugin, what):
    result = fly(tmp_path, kind, plugin)
    assert result.verdict == f"failed: {kind} {plugin!r} {IN_PROCESS}: {what}"
    events = [json.loads(line) for line in (result.run_dir / "events.jsonl").read_text().splitlines()]
    names = [e["event"] for e in events]
    if "run_start" in names:  # it flew: the landing is commanded (and a broken platform's refusal logged)
        assert "landing" in names and names.index("landing") > names.index("run_start")
    else:
        assert "landing" not in names


def test_a_planner_touring_a_viewpoint_it_was_not_offered_fails_the_run(tmp_path):
    result = fly(tmp_path, "planner", "stranger")
    assert re.fullmatch(
        rf"failed: planner 'stranger' {re.escape(IN_PROCESS)}: plan\(\): stop 0: viewpoint 987654, which was "
        r"not among the request's \d+ viewpoints",
        result.verdict,
    ), result.verdict


def test_a_planner_raising_on_every_call_fails_the_run_after_landing(tmp_path):
    result = fly(tmp_path, "planner", "raising")
    assert result.verdict == (
        f"failed: planner 'raising' {IN_PROCESS}: plan() raised RuntimeError: solver diverged "
        "(5 plans in a row failed)"
    )
    events = [json.loads(line) for line in (result.run_dir / "events.jsonl").read_text().splitlines()]
    assert sum(e["event"] == "planner_error" for e in events) == 5
    assert any(e["event"] == "mission_end" for e in events)  # it came home and landed first


def test_a_shipped_backend_is_named_with_its_distribution():
    registry = build_plugin_manager()
    label = registry.origin("planner", "greedy")
    assert re.fullmatch(r"planner 'greedy' from dist amslam \S+", label), label
    assert str(Boundary({"planner": label}).fault("planner", "x")) == f"{label}: x"
