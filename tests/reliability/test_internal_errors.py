"""A bug inside a goal's work is answered with INTERNAL_ERROR, never left to the default result.

Raised out of an action callback, the goal ends without a result and the client reads a
default-constructed one, whose error code 0 is SUCCESS: a demo once reported a RunTask that had
crashed on a TypeError as succeeded with 0 pushes. Each node is constructed in this process (never
spun) and its goal handler run with work that raises.
"""

from __future__ import annotations

import pytest

rclpy = pytest.importorskip("rclpy")
from tsrrt_executor.executor_node import ExecutorNode  # noqa: E402
from tsrrt_interfaces.action import ExecutePrimitive, RunTask  # noqa: E402
from tsrrt_planner.planner_node import PlannerNode  # noqa: E402


class _GoalHandle:
    """The part of rclpy's ServerGoalHandle the handlers touch."""

    def __init__(self, request) -> None:
        self.request = request
        self.ended_as: str | None = None

    def succeed(self) -> None:
        self.ended_as = "succeeded"

    def abort(self) -> None:
        self.ended_as = "aborted"

    def canceled(self) -> None:
        self.ended_as = "canceled"


@pytest.fixture()
def ros():
    rclpy.init(args=["test_internal_errors", "--ros-args", "--log-level", "fatal"])
    yield
    rclpy.try_shutdown()


def _bug() -> None:
    raise TypeError("unexpected keyword argument 'margin'")


def test_a_bug_in_a_planner_goal_is_an_internal_error(ros):
    node = PlannerNode()
    try:
        handle = _GoalHandle(RunTask.Goal())
        result = node._run_exclusive(handle, RunTask.Result(), _bug)
    finally:
        node.destroy_node()
    assert handle.ended_as == "aborted"
    assert result.error_code == RunTask.Result.INTERNAL_ERROR
    assert "TypeError" in result.error_msg and "margin" in result.error_msg


def test_a_bug_in_an_executor_goal_is_an_internal_error(ros, monkeypatch):
    node = ExecutorNode()
    try:
        monkeypatch.setattr(node, "_run", lambda goal_handle, result: _bug())
        handle = _GoalHandle(ExecutePrimitive.Goal(object_id="box", primitive=1))
        result = node._execute(handle)
    finally:
        node.destroy_node()
    assert handle.ended_as == "aborted"
    assert result.error_code == ExecutePrimitive.Result.INTERNAL_ERROR
    assert "TypeError" in result.error_msg
