"""The state of a recorded run at a moment: tree statuses, blackboard, robot pose, current tour.

The page's script (``timeline.js``) does the same reconstruction in the browser; this module is
the reference the tests hold it to, and what ``amslam view RUN --at T`` prints in a terminal.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field
from typing import Any

INVALID = "INVALID"


@dataclass
class TreeState:
    """Each node's ``[status, feedback]`` and the blackboard after the last change at or before ``t``."""

    t: float
    tick: int
    nodes: dict[int, list[str]] = field(default_factory=dict)
    blackboard: dict[str, Any] = field(default_factory=dict)

    def status(self, node_id: int) -> str:
        return self.nodes.get(node_id, [INVALID, ""])[0]

    def feedback(self, node_id: int) -> str:
        return self.nodes.get(node_id, [INVALID, ""])[1]


def tree_state_at(records: list[list[Any]], t: float) -> TreeState:
    """Replay change records ``[t, tick, nodes, blackboard]`` (ascending t) up to and including ``t``.

    A node never mentioned yet is INVALID (py_trees' status of a node not ticked), a blackboard
    key never written is absent.
    """
    state = TreeState(t=t, tick=0)
    times = [r[0] for r in records]
    for rec_t, tick, nodes, blackboard in records[: bisect.bisect_right(times, t)]:
        del rec_t
        state.tick = tick
        for key, value in nodes.items():
            state.nodes[int(key)] = list(value)
        state.blackboard.update(blackboard)
    return state


def pose_at(trajectory: list[list[float]], t: float) -> list[float] | None:
    """``[x, y, z, yaw]`` at ``t``, interpolated between the samples ``[t, x, y, z, yaw]`` around it.

    Before the first sample: None (the robot's pose is not known yet). After the last: the last.
    Yaw is interpolated along the shorter arc.
    """
    if not trajectory or t < trajectory[0][0]:
        return None
    times = [p[0] for p in trajectory]
    i = bisect.bisect_right(times, t) - 1
    if i >= len(trajectory) - 1:
        return list(trajectory[-1][1:5])
    a, b = trajectory[i], trajectory[i + 1]
    span = b[0] - a[0]
    s = (t - a[0]) / span if span > 0 else 0.0
    dyaw = math.atan2(math.sin(b[4] - a[4]), math.cos(b[4] - a[4]))
    yaw = math.atan2(math.sin(a[4] + s * dyaw), math.cos(a[4] + s * dyaw))
    return [a[k] + s * (b[k] - a[k]) for k in (1, 2, 3)] + [yaw]


def tour_at(events: list[dict[str, Any]], t: float) -> list[list[Any]]:
    """The tour ``[[kind, x, y, z], ...]`` of the latest ``replan`` event at or before ``t``."""
    tour: list[list[Any]] = []
    for event in events:
        if event.get("t", 0.0) > t:
            break
        if event.get("event") == "replan":
            tour = event.get("tour") or []
    return tour


def slc_viewpoints_until(events: list[dict[str, Any]], t: float) -> list[list[float]]:
    """Every distinct SLC viewpoint any tour held up to ``t`` (``[x, y, z]``)."""
    seen: dict[tuple[float, ...], list[float]] = {}
    for event in events:
        if event.get("t", 0.0) > t:
            break
        if event.get("event") == "replan":
            for kind, *xyz in event.get("tour") or []:
                if kind == "slc":
                    seen.setdefault(tuple(xyz), list(xyz))
    return list(seen.values())


STATUS_MARK = {"SUCCESS": "✔", "FAILURE": "✘", "RUNNING": "▶", INVALID: "·"}


def render_text(structure: list[dict[str, Any]], state: TreeState) -> str:
    """The tree at a moment as indented text: status mark, name, status and feedback per node."""
    children: dict[int | None, list[dict[str, Any]]] = {}
    for node in structure:
        children.setdefault(node["parent"], []).append(node)
    lines = [f"t = {state.t:.1f} s (tick {state.tick})"]

    def walk(node: dict[str, Any], depth: int) -> None:
        status, feedback = state.nodes.get(node["id"], [INVALID, ""])
        text = f"{'    ' * depth}{STATUS_MARK.get(status, '?')} {node['name']} [{status}]"
        if feedback:  # an INVALID node keeps the message of its last run: say so
            text += f"  — last: {feedback}" if status == INVALID else f"  — {feedback}"
        lines.append(text)
        for child in children.get(node["id"], []):
            walk(child, depth + 1)

    for root in children.get(None, []):
        walk(root, 0)
    return "\n".join(lines)
