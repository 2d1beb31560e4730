"""tsrrt_common.ros_node.HandoffExecutor: every node's executor hands each callback out once.

rclpy 7.1's MultiThreadedExecutor handed a callback that a worker had not started yet out again,
going round its wait loop several times per message; this counts the rounds.
"""

from __future__ import annotations

import threading
import time

import pytest

pytestmark = pytest.mark.integration

rclpy = pytest.importorskip("rclpy")
from std_msgs.msg import String  # noqa: E402

from tsrrt_common.ros_node import HandoffExecutor  # noqa: E402

MESSAGES = 40


class CountingExecutor(HandoffExecutor):
    """Counts how often the executor looked for work (once per callback handed out)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.lookups = 0

    def wait_for_ready_callbacks(self, *args, **kwargs):
        self.lookups += 1
        return super().wait_for_ready_callbacks(*args, **kwargs)


def test_each_message_is_handed_to_a_worker_once(ros_env) -> None:
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    listener = rclpy.create_node("handoff_listener", context=context)
    talker = rclpy.create_node("handoff_talker", context=context)
    received: list[str] = []
    listener.create_subscription(String, "handoff_chatter", lambda m: received.append(m.data),
                                 MESSAGES)
    publisher = talker.create_publisher(String, "handoff_chatter", MESSAGES)
    executor = CountingExecutor(num_threads=3, context=context)
    executor.add_node(listener)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        deadline = time.monotonic() + 20.0
        while publisher.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        lookups_before = executor.lookups
        for index in range(MESSAGES):
            publisher.publish(String(data=str(index)))
            time.sleep(0.02)
        while len(received) < MESSAGES and time.monotonic() < deadline:
            time.sleep(0.05)
        lookups = executor.lookups - lookups_before
    finally:
        executor.shutdown()
        spinner.join(timeout=5.0)
        talker.destroy_node()
        listener.destroy_node()
        rclpy.shutdown(context=context)
    assert sorted(received, key=int) == [str(i) for i in range(MESSAGES)]
    # One lookup per message, and a few for what else the executor was woken by (discovery).
    assert lookups <= MESSAGES + 10, f"{lookups} lookups for {MESSAGES} messages"


class UnwokenExecutor(HandoffExecutor):
    """Not woken when its context shuts down: as on a signal, when rclpy wakes the executor and
    then shuts the context down from a thread of its own."""

    def wake(self) -> None:
        pass


def test_spin_ends_when_the_context_shuts_down_without_waking_it(ros_env) -> None:
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    node = rclpy.create_node("handoff_unwoken", context=context)
    executor = UnwokenExecutor(num_threads=2, context=context)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    time.sleep(0.3)
    rclpy.shutdown(context=context)
    spinner.join(timeout=5.0)
    stuck = spinner.is_alive()
    executor.shutdown(timeout_sec=1.0)
    node.destroy_node()
    assert not stuck, "the executor went on waiting after its context shut down"
