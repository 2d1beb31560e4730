"""Simulator benchmark: physics speed, real-time factor with the camera, render time, tracking.

    python -m tsrrt_sim.bench --json out/sim_bench.json

Render time is measured in this process with the arm in its ready posture (close to the camera,
the slow case); the real-time factor with the camera renders 10 frames per wall second in a
RenderWorker process, as the node does. The machine's load is recorded beside the numbers.

The test trajectory is a push like the executor's: the ball descends beside the eraser of the
`obstacle` scenario, pushes it 8 cm sideways at 5 cm/s and lifts off. The Cartesian path is turned
into joint waypoints (20 per second, positions and velocities: cubic interpolation) by damped
least-squares IK with the hand kept pointing down. Tracking error is the distance between the
tool positions of the desired and the measured joint positions, at every physics step.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

from tsrrt_common.errors import TsrrtError
from tsrrt_common.robot_model import ARM_JOINT_NAMES, BALL_RADIUS, READY_POSTURE, TOOL_FRAME
from tsrrt_common.scenario import Scenario, load_scenario
from tsrrt_sim.kinematics import PusherKinematics
from tsrrt_sim.render_worker import RenderWorker
from tsrrt_sim.trajectory_controller import JointTrajectory, validate_trajectory
from tsrrt_sim.world import SimWorld

CAMERA_RATE_HZ = 10.0
WAYPOINT_RATE_HZ = 20.0
TICK_STEPS = 6          # physics steps between camera checks: the node's default clock tick
REPETITIONS = 4


def min_jerk(s: np.ndarray) -> np.ndarray:
    """Smooth 0 -> 1 time scaling with zero velocity and acceleration at both ends."""
    return 10 * s**3 - 15 * s**4 + 6 * s**5


def cartesian_push_path(start_tool: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Waypoint times (N,) and tool positions (N, 3) of the benchmark push.

    The eraser of the `obstacle` scenario lies at (0.42, -0.16) along x; the ball approaches its
    -y face from above, pushes it 8 cm towards +y and lifts off.
    """
    ball_z = BALL_RADIUS + 0.004
    above = np.array([0.42, -0.22, 0.10])
    contact_start = np.array([0.42, -0.22, ball_z])
    push_end = np.array([0.42, -0.10, ball_z])
    lifted = np.array([0.42, -0.10, 0.10])
    legs = [(start_tool, above, 2.0), (above, contact_start, 1.0),
            (contact_start, push_end, 0.12 / 0.05), (push_end, lifted, 1.0)]
    times, points, t0 = [0.0], [start_tool], 0.0
    for begin, end, duration in legs:
        count = max(2, math.ceil(duration * WAYPOINT_RATE_HZ))
        s = np.linspace(0.0, 1.0, count + 1)[1:]
        times += (t0 + s * duration).tolist()
        points += [begin + (end - begin) * v for v in min_jerk(s)]
        t0 += duration
    return np.array(times), np.array(points)


def tool_path_to_joints(kinematics: PusherKinematics, q_start: np.ndarray,
                        tool_points: np.ndarray) -> np.ndarray:
    """Joint positions (N, 7) reaching each tool point (N, 3) with the start's hand orientation.

    Damped least squares on the 6-D tool pose error, warm-started from the previous solution.
    """
    model = kinematics.model
    data = model.createData()
    frame = model.getFrameId(TOOL_FRAME)
    pin.framesForwardKinematics(model, data, q_start)
    rotation_goal = data.oMf[frame].rotation.copy()
    solutions, q = [], q_start.copy()
    for point in tool_points:
        goal = pin.SE3(rotation_goal, point)
        for _ in range(100):
            pin.framesForwardKinematics(model, data, q)
            error = pin.log6(data.oMf[frame].actInv(goal)).vector
            if np.linalg.norm(error) < 1e-7:
                break
            jacobian = pin.computeFrameJacobian(model, data, q, frame, pin.LOCAL)
            step = jacobian.T @ np.linalg.solve(jacobian @ jacobian.T + 1e-6 * np.eye(6), error)
            q = np.clip(q + step, model.lowerPositionLimit, model.upperPositionLimit)
        solutions.append(q.copy())
    return np.array(solutions)


def push_trajectory(kinematics: PusherKinematics) -> JointTrajectory:
    """The benchmark push as a validated joint trajectory from READY_POSTURE."""
    q_start = np.array(READY_POSTURE)
    times, tool_points = cartesian_push_path(kinematics.tool_position(q_start))
    positions = tool_path_to_joints(kinematics, q_start, tool_points)
    velocities = np.gradient(positions, times, axis=0)
    velocities[[0, -1]] = 0.0
    return validate_trajectory(ARM_JOINT_NAMES, times[1:].tolist(), positions[1:].tolist(),
                               velocities[1:].tolist(), [[]] * (len(times) - 1),
                               kinematics.limits)


def run_push(world: SimWorld, trajectory: JointTrajectory, worker: RenderWorker | None
             ) -> dict[str, float]:
    """Execute the push; with a worker, request a frame every 1/CAMERA_RATE_HZ wall seconds."""
    controller = world.controller
    execution = controller.start(trajectory, controller.default_tolerances, world.sim_time,
                                 world.sim_time)
    sim_start, wall_start = world.sim_time, time.perf_counter()
    next_frame, frames = wall_start, 0
    while not execution.done:
        world.step(TICK_STEPS)
        if worker is not None:
            if worker.poll() is not None:
                frames += 1
            now = time.perf_counter()
            if now >= next_frame and not worker.busy:
                worker.request(world.visual_state())
                next_frame = max(next_frame + 1.0 / CAMERA_RATE_HZ, now)
    wall = time.perf_counter() - wall_start
    sim = world.sim_time - sim_start
    return {"status": execution.status.value, "error": execution.error_string,
            "sim_s": sim, "wall_s": wall, "frames": frames,
            "rms_mm": execution.tool_rms_error * 1e3, "max_mm": execution.tool_error_max * 1e3}


def run_repeatedly(world: SimWorld, scenario: Scenario, trajectory: JointTrajectory,
                   worker: RenderWorker | None) -> dict[str, float]:
    """REPETITIONS pushes from a freshly loaded scenario each; totals and tracking extremes."""
    totals = {"sim_s": 0.0, "wall_s": 0.0, "frames": 0, "sum_sq_mm": 0.0, "max_mm": 0.0,
              "pushed_m": 0.0}
    for _ in range(REPETITIONS):
        world.load_scenario(scenario)
        if worker is not None:
            worker.load_scenario(scenario)
        world.settle(0.5)
        before = world.object_poses()["eraser"]
        run = run_push(world, trajectory, worker)
        if run["status"] != "succeeded":
            raise TsrrtError(f"benchmark push {run['status']}: {run['error']}")
        after = world.object_poses()["eraser"]
        for key in ("sim_s", "wall_s", "frames"):
            totals[key] += run[key]
        totals["sum_sq_mm"] += run["rms_mm"] ** 2 / REPETITIONS
        totals["max_mm"] = max(totals["max_mm"], run["max_mm"])
        totals["pushed_m"] = math.dist((before.x, before.y), (after.x, after.y))
    return totals


def run_benchmark() -> dict[str, float]:
    scenario = load_scenario("obstacle")
    # The push starts from the ready posture, and render time is measured with the arm there.
    world = SimWorld(scenario, initial_posture=READY_POSTURE)
    worker = RenderWorker(scenario, world.camera)
    try:
        trajectory = push_trajectory(world.kinematics)
        no_camera = run_repeatedly(world, scenario, trajectory, worker=None)
        with_camera = run_repeatedly(world, scenario, trajectory, worker=worker)
        world.load_scenario(scenario)
        renders = []
        for _ in range(10):
            started = time.perf_counter()
            world.render()
            renders.append(time.perf_counter() - started)
    finally:
        worker.close()
        world.close()
    return {
        "steps_per_s": no_camera["sim_s"] * world.physics_hz / no_camera["wall_s"],
        "real_time_factor": with_camera["sim_s"] / with_camera["wall_s"],
        "real_time_factor_no_camera": no_camera["sim_s"] / no_camera["wall_s"],
        "camera_frames_per_wall_s": with_camera["frames"] / with_camera["wall_s"],
        "render_ms": 1e3 * float(np.mean(renders)),
        "tracking_rms_mm": math.sqrt(no_camera["sum_sq_mm"]),
        "tracking_max_mm": no_camera["max_mm"],
        "eraser_pushed_m": no_camera["pushed_m"],
        "simulated_s": no_camera["sim_s"] + with_camera["sim_s"],
        "cpu_count": os.cpu_count(),
        "load_average_1min": os.getloadavg()[0],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, help="also write the results to this file")
    args = parser.parse_args(argv)
    results = run_benchmark()
    for key, value in results.items():
        print(f"{key:28s} {value:.3f}" if isinstance(value, float) else f"{key:28s} {value}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
