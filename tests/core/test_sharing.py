"""The thread rule's lock, at the one interleaving that corrupts a map: a frame fused mid-query.

The planner thread asks the map for path costs; the map builds its free-space search graph from
the voxels and caches it under the map's version. If the control thread fuses a frame while the
graph is being built, the graph is of the old voxels but is cached under the new version, and
every later query — GoTo's paths on the control thread too — answers from the old map. The test
pauses the planner thread inside the graph build (after the voxels were read), lets the control
thread fuse a frame that opens new free space, then lets the planner finish: through
:class:`amslam.sharing.Shared` the fusion waits for the query, and the next query sees the frame.
"""

from __future__ import annotations

import sys
import threading

import numpy as np

from amslam.lib.voxel_map import VoxelMapParams
from amslam.plugins.voxel_numpy.backend import NumpyVoxelMap
from amslam.sharing import Shared
from amslam.testing.mapping import CAMERA, camera_pose, make_context, wall_depth
from tests.core.pausing import PauseAtCall

#: from the origin to 2 m ahead (seen by the first frame) and to 2 m left (seen only by the second)
PLACES = np.array([[0.5, 0.0, 0.0], [2.0, 0.0, 0.0], [0.5, 2.0, 0.0]])
AHEAD = (wall_depth(), CAMERA.K, camera_pose(yaw=0.0))
LEFT = (wall_depth(), CAMERA.K, camera_pose(yaw=np.pi / 2))


def fused(tmp_path, *frames) -> NumpyVoxelMap:
    mapping = NumpyVoxelMap()
    mapping.configure(VoxelMapParams(), make_context(tmp_path))
    for depth, K, T in frames:
        mapping.integrate_global(depth, K, T)
    return mapping


def test_a_frame_fused_during_a_path_query_reaches_the_next_query(tmp_path):
    expected = fused(tmp_path / "both", AHEAD, LEFT).path_costs(PLACES, PLACES)
    stale = fused(tmp_path / "ahead", AHEAD).path_costs(PLACES, PLACES)
    assert not np.array_equal(expected, stale), "the second frame must change the path costs"

    shared = Shared(fused(tmp_path / "shared", AHEAD))
    # the search graph's obstacles are computed from the dense states the map just read
    pause = PauseAtCall("obstacles")

    def planner() -> None:
        sys.settrace(pause)
        try:
            shared.path_costs(PLACES, PLACES)
        finally:
            sys.settrace(None)

    planning = threading.Thread(target=planner)
    planning.start()
    assert pause.paused.wait(timeout=10.0), "the planner thread never built a search graph"
    control = threading.Thread(target=shared.integrate_global, args=LEFT)
    control.start()
    control.join(timeout=0.5)  # through the lock the fusion waits for the query to finish
    fused_mid_query = not control.is_alive()
    pause.resume.set()
    planning.join()
    control.join()
    assert not fused_mid_query, "the frame was fused while the planner thread was reading the map"
    np.testing.assert_array_equal(shared.path_costs(PLACES, PLACES), expected)
