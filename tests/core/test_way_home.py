"""The run's metrics say whether the vehicle came home: "completed" alone does not."""

from __future__ import annotations

import py_trees
from py_trees.common import Status

from amslam.runner import Runner


class Leaf(py_trees.behaviour.Behaviour):
    """Ends with a given status and feedback, like a ``GoTo`` leaf does."""

    def __init__(self, name: str, status: Status, why: str = ""):
        super().__init__(name)
        self.result, self.why = status, why

    def update(self) -> Status:
        self.feedback_message = self.why
        return self.result


def ended(*children: py_trees.behaviour.Behaviour) -> py_trees.behaviour.Behaviour:
    root = py_trees.composites.Sequence(
        "Mission",
        memory=True,
        children=[
            py_trees.decorators.FailureIsSuccess(
                "ReturnHome", py_trees.composites.Sequence("Steps", memory=True, children=list(children))
            ),
            Leaf("Land", Status.SUCCESS, "landed"),
        ],
    )
    root.tick_once()
    assert root.status == Status.SUCCESS  # the mission "completed" either way
    return root


def test_a_way_home_given_up_is_named_with_its_reason() -> None:
    gave_up = ended(Leaf("GoHome", Status.FAILURE, "the local map showed the way blocked 3 times"))
    assert Runner._home_outcome(gave_up) == "gave up: the local map showed the way blocked 3 times"
    assert Runner._home_outcome(ended(Leaf("GoHome", Status.SUCCESS, "arrived"))) == "came home"
    # a tree without a way home says nothing of it
    assert Runner._home_outcome(ended(Leaf("Hover", Status.SUCCESS))) is None
