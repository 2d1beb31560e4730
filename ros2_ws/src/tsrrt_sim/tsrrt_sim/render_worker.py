"""Camera rendering in a separate process, so that physics keeps stepping while a frame is drawn.

TinyRenderer takes 30-70 ms per 640x480 frame (more when the arm is close to the camera). Drawn
in the physics process at 10 frames per wall second, that would take most of the time physics
needs for a real-time factor of 20. The worker holds its own copy of the scene (the same
SimWorld code, never stepped); each request carries the arm's joint positions and the objects'
poses, which the worker applies before rendering.
"""

from __future__ import annotations

import multiprocessing
import signal
import time
from multiprocessing.connection import Connection

from tsrrt_common.camera import OverheadCamera
from tsrrt_common.scenario import Scenario
from tsrrt_sim.world import DEFAULT_CAMERA, CameraFrame, SimWorld, SimWorldError, VisualState

_STARTUP_TIMEOUT_S = 60.0
_STOP_DRAIN_TIMEOUT_S = 2.0   # longest a frame in flight is waited for when closing


def _serve(connection: Connection, scenario: Scenario, camera: OverheadCamera,
           simple_robot_visuals: bool) -> None:
    """Worker process main loop: ('load', Scenario) and ('render', VisualState) requests."""
    # The parent decides when this process ends (a closed pipe or "stop"); a Ctrl-C or SIGTERM
    # sent to the whole process group must not kill it half-way through a reply, nor before the
    # parent has stopped the physics thread that is waiting for its frames.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    world = SimWorld(scenario, camera=camera, simple_robot_visuals=simple_robot_visuals)
    connection.send(("ready", None))
    try:
        while True:
            try:
                command, payload = connection.recv()
            except EOFError:
                return
            if command == "load":
                world.load_scenario(payload)
            elif command == "render":
                started = time.perf_counter()
                world.apply_visual_state(payload)
                frame = world.render()
                connection.send(("frame", (frame, time.perf_counter() - started)))
            elif command == "stop":
                return
    finally:
        world.close()


class RenderWorker:
    """A render process mirroring one SimWorld's scene; at most one frame in flight.

    Args:
        scenario: the scene to build (keep it in step with load_scenario()).
        camera: the camera to render with.
        simple_robot_visuals: as for SimWorld.
    """

    def __init__(self, scenario: Scenario, camera: OverheadCamera = DEFAULT_CAMERA,
                 simple_robot_visuals: bool = True) -> None:
        context = multiprocessing.get_context("spawn")   # never fork a process with threads
        self._connection, child_end = context.Pipe()
        self._process = context.Process(
            target=_serve, args=(child_end, scenario, camera, simple_robot_visuals),
            name="tsrrt_render_worker", daemon=True)
        self._process.start()
        child_end.close()
        if not self._connection.poll(_STARTUP_TIMEOUT_S):
            self.close()
            raise SimWorldError("the render worker did not start within "
                                f"{_STARTUP_TIMEOUT_S:.0f} s")
        self._receive()
        self._busy = False
        self.last_render_seconds = 0.0

    def _receive(self) -> object:
        try:
            kind, payload = self._connection.recv()
        except (EOFError, OSError):
            raise SimWorldError(
                f"the render worker died (exit code {self._process.exitcode})") from None
        return payload

    @property
    def busy(self) -> bool:
        """True while a requested frame has not been collected."""
        return self._busy

    def load_scenario(self, scenario: Scenario) -> None:
        """Rebuild the worker's scene; a frame in flight is dropped."""
        if self._busy:
            self._receive()
            self._busy = False
        self._connection.send(("load", scenario))

    def request(self, state: VisualState) -> None:
        """Start rendering `state`; call only when not busy."""
        if self._busy:
            raise SimWorldError("a frame is already being rendered")
        self._connection.send(("render", state))
        self._busy = True

    def poll(self, timeout: float = 0.0) -> CameraFrame | None:
        """The requested frame if it is ready within `timeout` seconds, else None."""
        if not self._busy or not self._connection.poll(timeout):
            return None
        frame, self.last_render_seconds = self._receive()
        self._busy = False
        return frame

    def render(self, state: VisualState) -> CameraFrame:
        """Render `state` and wait for the frame."""
        self.request(state)
        frame = self.poll(timeout=_STARTUP_TIMEOUT_S)
        if frame is None:
            raise SimWorldError(f"no frame from the render worker in {_STARTUP_TIMEOUT_S:.0f} s")
        return frame

    def close(self) -> None:
        """Stop the worker process (idempotent)."""
        if self._process.is_alive():
            try:
                # A frame in flight fills the pipe and blocks the worker until it is read: it
                # would never see "stop", and closing would wait out the join and kill it.
                if self._busy and self._connection.poll(_STOP_DRAIN_TIMEOUT_S):
                    self._connection.recv()
                self._busy = False
                self._connection.send(("stop", None))
            except (EOFError, OSError):
                pass
            self._process.join(timeout=5.0)
            if self._process.is_alive():
                self._process.kill()
                self._process.join()
        self._connection.close()
