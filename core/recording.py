"""Compact recording of the behaviour tree: one line per tick where something changed.

``tree.jsonl`` starts with the tree's structure (node ids, names, types, parents), then holds a
record ``{"t", "tick", "nodes": {id: [status, feedback]}, "blackboard": {key: value}}`` for every
tick in which a node's status or feedback or a blackboard value changed — changes only.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import py_trees

from amslam.rundir import RunDir
from amslam.types import TourItem


def summarise(value: Any) -> Any:
    """A blackboard value as small JSON: tours as [kind, x, y, z] lists, arrays rounded."""
    if isinstance(value, TourItem):
        return [value.kind.value, *np.round(value.position, 2).tolist()]
    if isinstance(value, list | tuple):
        return [summarise(v) for v in value[:50]]
    if isinstance(value, np.ndarray):
        return np.round(value, 3).tolist()
    if isinstance(value, float):
        return round(value, 3)
    if isinstance(value, dict):
        return {k: summarise(v) for k, v in value.items()}
    if value is None or isinstance(value, str | int | bool):
        return value
    return str(value)


def _preorder(node: py_trees.behaviour.Behaviour) -> list[py_trees.behaviour.Behaviour]:
    """Root first, children in order (``iterate()`` yields children before their parents)."""
    out = [node]
    for child in node.children:
        out += _preorder(child)
    return out


class TreeRecorder:
    """Writes the tree's structure once, then its changes after every tick."""

    def __init__(self, tree: py_trees.trees.BehaviourTree, rundir: RunDir):
        self.tree = tree
        self.rundir = rundir
        self.nodes = _preorder(tree.root)
        self.ids = {node.id: i for i, node in enumerate(self.nodes)}
        self.last_nodes: dict[int, list] = {}
        self.last_bb: dict[str, Any] = {}
        structure = [
            {
                "id": self.ids[n.id],
                "name": n.name,
                "type": type(n).__name__,
                "parent": self.ids[n.parent.id] if n.parent is not None and n.parent.id in self.ids else None,
            }
            for n in self.nodes
        ]
        rundir.tree_change({"structure": structure})

    def record(self, t: float) -> None:
        nodes = {}
        for node in self.nodes:
            state = [node.status.value, node.feedback_message]
            i = self.ids[node.id]
            if self.last_nodes.get(i) != state:
                nodes[i] = state
                self.last_nodes[i] = state
        bb = {}
        for key, value in py_trees.blackboard.Blackboard.storage.items():
            small = summarise(value)
            if self.last_bb.get(key, object()) != small:
                bb[key] = small
                self.last_bb[key] = small
        if nodes or bb:
            self.rundir.tree_change(
                {"t": round(t, 3), "tick": self.tree.count, "nodes": nodes, "blackboard": bb}
            )

    def close(self) -> None:
        """Nothing buffered: every record is flushed when written."""
