"""What every tsrrt node shares with rclpy: a race-free action client, an executor that does
not spin idle, the node's main loop and time stamps.

The one module of tsrrt_common that imports rclpy; the ROS-free cores never import it.
"""

from __future__ import annotations

import faulthandler
import signal
import threading
import time
import traceback
from collections.abc import Callable
from typing import Any

import rclpy
import rclpy.action
from builtin_interfaces.msg import Duration as DurationMessage
from builtin_interfaces.msg import Time as TimeMessage
from rclpy.exceptions import ParameterException
from rclpy.executors import (
    ConditionReachedException,
    ExternalShutdownException,
    MultiThreadedExecutor,
    ShutdownException,
    TimeoutException,
)
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.node import Node

from tsrrt_common.errors import TsrrtError

# A node still shutting down this long after it began prints every thread's stack to stderr (its
# log): a process that hangs on a signal is otherwise only a SIGKILL and a silent log.
SHUTDOWN_REPORT_S = 10.0
# rclpy shuts its context down on SIGINT/SIGTERM from a thread of its own, a moment after the
# signal; a start that fails within this long of it (a helper process killed by the same signal
# to the process group) is part of the shutdown, not a refusal.
SIGNAL_SHUTDOWN_GRACE_S = 1.0
HANDOFF_POLL_S = 0.1  # how often a spin waiting for a worker to start checks for shutdown
SHUTDOWN_POLL_S = 0.5  # how often an idle spin wakes to check whether its context shut down
# Longest wait asked of perception in one request for a settled observation. A service response
# can be lost: rmw_fastrtps drops one sent before the server has matched a new client's reader
# ("failed to send response (timeout)", seen after a perception restart), and the client then
# hears nothing; a longer wait is asked as several requests, so a lost answer costs this much.
SETTLE_REQUEST_S = 2.0


def shutting_down() -> bool:
    """True once rclpy's context is down (SIGINT/SIGTERM). The executor then spins no more, so a
    future still pending never completes, and rclpy destroys the node without waiting for its
    running callbacks, yet the process exits only once every worker thread has returned: a goal
    must stop waiting and working then, and send nothing through its destroyed handle, or it
    holds the process past its stop grace (a fresh-clone CI run killed planner_node 15 s after
    SIGINT)."""
    return not rclpy.ok()


def answer_internal_error(node: Node, goal_handle: Any, result: Any, error: Exception) -> None:
    """Abort a goal whose work raised an exception no error path expects (a bug) with the
    result's INTERNAL_ERROR code, naming the exception, and log its traceback. Raised out of
    the callback instead, the goal would end without a result and the client would read the
    default one, whose code 0 is SUCCESS (a demo reported a crashed task as succeeded)."""
    node.get_logger().error(traceback.format_exc())
    result.error_code = result.INTERNAL_ERROR
    result.error_msg = f"internal error: {type(error).__name__}: {error}"
    goal_handle.abort()


def time_message(seconds: float) -> TimeMessage:
    """builtin_interfaces/Time of a time in seconds (e.g. simulation time)."""
    nanoseconds = round(seconds * 1e9)
    return TimeMessage(sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)


def seconds(stamp: TimeMessage | DurationMessage) -> float:
    """A builtin_interfaces/Time or Duration in seconds (the inverse of time_message)."""
    return stamp.sec + stamp.nanosec * 1e-9


class ActionClient(rclpy.action.ActionClient):
    """rclpy's ActionClient without its lost-response race (ros2/rclpy#1123).

    In rclpy 7.1 (Jazzy) `send_goal_async` sends the request before it registers the request's
    sequence number, so an executor thread that takes the response in between drops it ("Ignoring
    unexpected goal response") and the future never completes; on a loaded machine this stalls a
    push. Upstream fixed it with a lock (ros2/rclpy#1519) after the wheels pinned here were built;
    this is the same lock: requests are sent and registered, and responses taken, under it.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._request_lock = threading.RLock()

    def send_goal_async(self, *args: Any, **kwargs: Any) -> Any:
        with self._request_lock:
            return super().send_goal_async(*args, **kwargs)

    def _cancel_goal_async(self, *args: Any, **kwargs: Any) -> Any:
        with self._request_lock:
            return super()._cancel_goal_async(*args, **kwargs)

    def _get_result_async(self, *args: Any, **kwargs: Any) -> Any:
        with self._request_lock:
            return super()._get_result_async(*args, **kwargs)

    def take_data(self) -> Any:
        with self._request_lock:
            return super().take_data()


class HandoffExecutor(MultiThreadedExecutor):
    """rclpy's MultiThreadedExecutor without its idle spinning (ros2/rclpy#1452).

    In rclpy 7.1 (Jazzy) a callback handed to the thread pool but not yet started still counts as
    work to hand out, so until a worker picks it up (which the spinning thread, holding the GIL,
    delays) the executor hands it out again and builds and waits on a new wait set at once. Idle,
    with /clock and /joint_states at 20 Hz, each tsrrt node went round that loop 150-1600 times a
    second, 9-64 % of a core each on the 2-core machine the graph runs on, and perception fell
    behind the camera. Upstream fixed it (ros2/rclpy#1547) after the wheels pinned here were
    built; here the spinning thread waits until each callback has started before it looks for
    more work.
    """

    def spin(self) -> None:
        """Execute callbacks until shutdown, waking every SHUTDOWN_POLL_S to check for it.

        On SIGINT/SIGTERM rclpy triggers the executor's signal guard condition and then shuts
        the context down from a thread of its own, without the wake-up a Python shutdown gives;
        woken before the shutdown, a spin that waits without a timeout waited for good (a fresh
        planner_node, SIGTERM, killed 15 s later in the soak of a fresh-clone CI run)."""
        while self._context.ok() and not self._is_shutdown:
            self.spin_once(timeout_sec=SHUTDOWN_POLL_S)

    def _spin_once_impl(self, timeout_sec: float | None = None,
                        wait_condition: Callable[[], bool] = lambda: False) -> None:
        try:
            handler, _, _ = self.wait_for_ready_callbacks(timeout_sec, None, wait_condition)
        except (ExternalShutdownException, ShutdownException, TimeoutException,
                ConditionReachedException):
            return
        started = threading.Event()

        def start() -> None:
            started.set()
            handler()

        self._executor.submit(start)
        self._futures.append(handler)
        # Every worker may be busy (callbacks waiting on other servers): keep noticing shutdown.
        while not started.wait(HANDOFF_POLL_S):
            if self._is_shutdown or not self._context.ok():
                break
        for future in self._futures[:]:
            if future.done():
                self._futures.remove(future)
                future.result()  # raise any exception of the callback


def _stays_up(seconds: float) -> bool:
    """True when rclpy's context is still up `seconds` from now (False as soon as it is not)."""
    deadline = time.monotonic() + seconds
    while rclpy.ok():
        if time.monotonic() >= deadline:
            return True
        time.sleep(0.01)
    return False


def run_node(make_node: Callable[[], Node], name: str, threads: int,
             args: list[str] | None = None) -> None:
    """Spin a node until SIGINT/SIGTERM; a bad file or parameter refuses to start (exit 1), a
    signal while starting is a shutdown like any other (exit 0).

    A signal shuts the context down while executor threads may still be waiting; their
    "context is not valid" error is part of an orderly shutdown, not a crash.
    """
    # A process that will not stop gets SIGUSR1 before SIGKILL (processes.stop_process_group):
    # its threads' stacks then say where it hung, however far it got towards shutting down.
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    rclpy.init(args=args)
    node = None
    refused = False
    executor = HandoffExecutor(num_threads=threads)
    try:
        node = make_node()
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (TsrrtError, ParameterException) as error:
        if _stays_up(SIGNAL_SHUTDOWN_GRACE_S):   # else a signal stopped the start
            rclpy.logging.get_logger(name).fatal(f"cannot start: {error}")
            refused = True
    except rclpy_implementation.RCLError:
        if rclpy.ok():
            raise
    finally:
        faulthandler.dump_traceback_later(SHUTDOWN_REPORT_S)
        executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    if refused:
        raise SystemExit(1)
