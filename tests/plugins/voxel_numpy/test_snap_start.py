"""A path starts where the robot is, even where the map holds an occupied voxel."""

import numpy as np

from amslam.lib.free_space import FreeSpaceGraph
from amslam.lib.voxel_grid import FREE, OCCUPIED


def corridor_with_a_phantom_wall() -> FreeSpaceGraph:
    """A 4 m corridor of 0.25 m voxels, free but for one occupied voxel at x 1.0–1.25 m (a wall
    the map drew from poses SLAM corrected later) where the robot is."""
    states = np.full((16, 3, 3), FREE, dtype=np.int8)
    states[4, 1, 1] = OCCUPIED
    passable = states == FREE
    return FreeSpaceGraph(passable, np.zeros(3, np.int64), 0.25, 0.6, states)


def test_a_start_in_an_occupied_voxel_leaves_it_for_the_nearest_node() -> None:
    graph = corridor_with_a_phantom_wall()
    robot, goal = np.array([1.125, 0.375, 0.375]), np.array([3.625, 0.375, 0.375])
    cost = graph.costs(robot[None], goal[None])[0, 0]
    assert np.isfinite(cost) and 2.5 - 1e-9 <= cost <= 3.5  # round the wall voxel
    path = graph.shortest_path(robot, goal)
    assert path is not None and np.allclose(path[0], robot) and np.allclose(path[-1], goal)
    assert np.linalg.norm(path[1] - robot) <= 0.6


def test_a_goal_in_an_occupied_voxel_stays_off_the_graph() -> None:
    graph = corridor_with_a_phantom_wall()
    start, wall = np.array([3.625, 0.375, 0.375]), np.array([1.125, 0.375, 0.375])
    assert np.isinf(graph.costs(start[None], wall[None])[0, 0])
    assert graph.shortest_path(start, wall) is None
