"""Benchmark of primitive execution: planning time, tool tracking, wall time, displacements.

    python -m tsrrt_executor.bench --json PATH [--trials 5] [--scenarios clean tset3]

Runs each primitive on each object class of the scenarios (>= 5 trials each) and prints the
numbers issue 5 asks for; the JSON has keys ik_ms_per_primitive, tracking_rms_mm,
tracking_max_mm, wall_s_per_primitive, displacements[class][primitive] = {mean, std} with
[dx, dy, dtheta] in the object frame (metres, radians) -- the raw material of the paper's Fig. 3.

What is measured through what (also written into the JSON under "measured_through"):
- The world is tsrrt_sim.world.SimWorld (PyBullet + the sim's computed-torque trajectory
  controller) driven directly, WITHOUT the ROS graph: no sim node, no perception, no executor
  node. Object poses are the simulator's ground truth, not perception's estimates.
- ik_ms_per_primitive: wall time of primitive_plan.plan_primitive (reachability and clearance
  checks, IK, time parameterisation) per primitive.
- tracking_*: ball-centre error |FK(desired q) - FK(measured q)| at every physics step of the
  push segment (in contact), sampled like the controller does (before each step).
- wall_s_per_primitive: wall time of planning + simulating the trajectory + 0.5 s simulated
  settling, through the core at full sim speed (not through the ROS graph).
- Each trial puts one object of the class alone on the table at BENCH_CENTRE with a seeded
  random offset (+-2 cm, heading +-0.3 rad), so that trials differ the way learning pushes do.
  BENCH_CENTRE is 5 cm beyond the table centre: at the centre (0.45, 0) primitive 1 on the
  remote (0.18 m long) approaches from x = 0.33, at the near edge of the reachable workspace.
- A trial whose plan fails (unreachable, IK) is counted in "plan_failures" and skipped.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from tsrrt_common.geometry import Pose2D
from tsrrt_common.scenario import ObjectSpec, Scenario, load_scenario
from tsrrt_executor.errors import ExecutorError
from tsrrt_executor.inverse_kinematics import PusherIK
from tsrrt_executor.primitive_plan import PrimitivePlan, TableObject, plan_primitive
from tsrrt_executor.push_primitives import DEFAULT_PUSH_LENGTH, primitives_for

SETTLE_S = 0.5
BENCH_CENTRE = (0.50, 0.0)
POSITION_JITTER = 0.02
HEADING_JITTER = 0.3


def first_object_of_each_class(scenario: Scenario) -> list[ObjectSpec]:
    seen: dict[str, ObjectSpec] = {}
    for spec in scenario.objects:
        seen.setdefault(spec.object_class, spec)
    return list(seen.values())


def table_object(spec: ObjectSpec, pose: Pose2D) -> TableObject:
    return TableObject(spec.id, spec.shape, spec.length, spec.width, spec.height, pose)


def run_trial(world, ik: PusherIK, spec: ObjectSpec, primitive: int, pose: Pose2D,
              push_length: float) -> dict:
    """One push on `spec` alone at `pose`; returns timings, tracking errors and displacement."""
    from tsrrt_sim.trajectory_controller import JointTrajectory

    scenario = dataclasses.replace(world.scenario, objects=(dataclasses.replace(spec, pose=pose),),
                                   obstacles=())
    world.load_scenario(scenario)
    world.settle(0.2)
    before = world.object_poses()[spec.id]
    wall_start = time.perf_counter()
    plan: PrimitivePlan = plan_primitive(ik, table_object(spec, before), [], primitive,
                                         push_length, world.joint_state().positions)
    trajectory = plan.trajectory
    execution = world.controller.start(
        JointTrajectory(trajectory.times, trajectory.positions, trajectory.velocities,
                        trajectory.accelerations), world.controller.default_tolerances,
        world.sim_time, world.sim_time)
    start_time = world.sim_time
    push_times = trajectory.times[np.array([p == "push" for p in trajectory.segment_names])]
    push_window = (push_times[0] + start_time, push_times[-1] + start_time)
    errors = []
    while not execution.done:
        if push_window[0] <= world.sim_time <= push_window[1]:
            desired = execution.sample(world.sim_time).positions
            errors.append(np.linalg.norm(ik.tool_position(desired)
                                         - ik.tool_position(world.joint_state().positions)))
        world.step()
    world.settle(SETTLE_S)
    wall = time.perf_counter() - wall_start
    after = world.object_poses()[spec.id]
    return {
        "planning_ms": plan.planning_ms, "wall_s": wall, "sim_s": trajectory.duration,
        "errors": np.array(errors), "succeeded": execution.error_code == 0,
        "controller_message": execution.error_string,
        "displacement": before.displacement_in_object_frame(after),
    }


def run(scenario_names: list[str], trials: int, push_length: float, seed: int) -> dict:
    from tsrrt_sim.world import SimWorld

    ik = PusherIK()
    rng = np.random.default_rng(seed)
    planning_ms, walls, sims, all_errors = [], [], [], []
    displacements: dict[str, dict[str, dict[str, list[float]]]] = {}
    failures: list[str] = []
    plan_failures: list[str] = []
    for name in scenario_names:
        scenario = load_scenario(name)
        if not scenario.table.bounds[0] < BENCH_CENTRE[0] < scenario.table.bounds[2]:
            raise ExecutorError(f"scenario {name!r}: bench centre {BENCH_CENTRE} is off the table")
        world = SimWorld(scenario)
        centre = BENCH_CENTRE
        try:
            for spec in first_object_of_each_class(scenario):
                per_class = displacements.setdefault(spec.object_class, {})
                for primitive in primitives_for(spec.shape):
                    samples = []
                    for _ in range(trials):
                        pose = Pose2D(centre[0] + rng.uniform(-POSITION_JITTER, POSITION_JITTER),
                                      centre[1] + rng.uniform(-POSITION_JITTER, POSITION_JITTER),
                                      rng.uniform(-HEADING_JITTER, HEADING_JITTER))
                        try:
                            result = run_trial(world, ik, spec, primitive, pose, push_length)
                        except ExecutorError as error:
                            plan_failures.append(f"{spec.object_class} p{primitive}: {error}")
                            continue
                        if not result["succeeded"]:
                            failures.append(f"{spec.object_class} p{primitive}: "
                                            f"{result['controller_message']}")
                        planning_ms.append(result["planning_ms"])
                        walls.append(result["wall_s"])
                        sims.append(result["sim_s"])
                        all_errors.append(result["errors"])
                        samples.append(result["displacement"])
                    if len(samples) < 2:
                        continue
                    samples = np.array(samples)
                    per_class[str(primitive)] = {
                        "mean": samples.mean(axis=0).round(5).tolist(),
                        "std": samples.std(axis=0, ddof=1).round(5).tolist(),
                        "trials": len(samples),
                    }
        finally:
            world.close()
    errors = np.concatenate(all_errors)
    return {
        "measured_through": "tsrrt_sim.world.SimWorld core driven directly (no ROS graph); "
                            "object poses are simulator ground truth",
        "scenarios": scenario_names,
        "trials_per_primitive": trials,
        "push_length": push_length,
        "ik_ms_per_primitive": float(np.mean(planning_ms)),
        "ik_ms_per_primitive_median": float(np.median(planning_ms)),
        "ik_ms_per_primitive_max": float(np.max(planning_ms)),
        "tracking_rms_mm": float(np.sqrt(np.mean(errors ** 2)) * 1000.0),
        "tracking_max_mm": float(errors.max() * 1000.0),
        "wall_s_per_primitive": float(np.mean(walls)),
        "sim_s_per_primitive": float(np.mean(sims)),
        "controller_failures": failures,
        "plan_failures": plan_failures,
        "displacements": displacements,
    }


def print_report(report: dict) -> None:
    print(f"measured through: {report['measured_through']}")
    print(f"IK + trajectory per primitive: {report['ik_ms_per_primitive']:.1f} ms mean, "
          f"{report['ik_ms_per_primitive_median']:.1f} ms median, "
          f"{report['ik_ms_per_primitive_max']:.1f} ms max (the first loads the reachability "
          "grid; target <= 20 ms)")
    print(f"tool tracking during the push: {report['tracking_rms_mm']:.3f} mm RMS, "
          f"{report['tracking_max_mm']:.3f} mm max (target <= 1 mm RMS)")
    print(f"wall per primitive (core, full sim speed): {report['wall_s_per_primitive']:.2f} s "
          f"for {report['sim_s_per_primitive']:.2f} s of trajectory (target <= 0.5 s through "
          "the ROS graph)")
    for key in ("controller_failures", "plan_failures"):
        if report[key]:
            print(f"{key.replace('_', ' ')}: {report[key]}")
    print("displacement in the object frame, mean +- std over "
          f"{report['trials_per_primitive']} trials: dx, dy [mm], dtheta [deg]")
    for object_class, per_primitive in report["displacements"].items():
        for primitive, stats in per_primitive.items():
            mean, std = stats["mean"], stats["std"]
            print(f"  {object_class:10s} {primitive}: "
                  f"dx {mean[0] * 1000:7.1f} +- {std[0] * 1000:4.1f}  "
                  f"dy {mean[1] * 1000:7.1f} +- {std[1] * 1000:4.1f}  "
                  f"dth {math.degrees(mean[2]):6.1f} +- {math.degrees(std[2]):4.1f}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Benchmark of tsrrt_executor's primitives.")
    parser.add_argument("--json", type=Path, help="write the numbers to this JSON file")
    parser.add_argument("--trials", type=int, default=5, help="trials per (class, primitive)")
    parser.add_argument("--scenarios", nargs="+", default=["clean", "tset3"])
    parser.add_argument("--push-length", type=float, default=DEFAULT_PUSH_LENGTH)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.trials < 2:
        parser.error("--trials must be at least 2 (a standard deviation is reported)")
    report = run(args.scenarios, args.trials, args.push_length, args.seed)
    print_report(report)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
