"""The PyBullet world: resting objects, tracking, goal outcomes, disturbances and the camera."""

import dataclasses
import math

import numpy as np
import pytest

from tsrrt_common.geometry import angle_difference_modulo_symmetry
from tsrrt_common.robot_model import ARM_JOINT_NAMES, OBSERVE_POSTURE, READY_POSTURE
from tsrrt_common.scenario import load_scenario, parse_scenario, shipped_scenarios
from tsrrt_sim.bench import push_trajectory
from tsrrt_sim.render_worker import RenderWorker
from tsrrt_sim.trajectory_controller import (
    ExecutionStatus,
    Tolerances,
    TrajectoryError,
    TrajectoryErrorCode,
    validate_trajectory,
)
from tsrrt_sim.world import SimWorld, SimWorldError


@pytest.fixture
def world():
    # Tracking and pushing are tested from the ready posture, above the table.
    sim = SimWorld(load_scenario("obstacle"), initial_posture=READY_POSTURE)
    sim.settle(0.5)
    yield sim
    sim.close()


def joint_trajectory(world, targets, times, with_velocities=True):
    """Trajectory through `targets` (list of (7,)) with zero velocity at each."""
    velocities = [[0.0] * 7 for _ in targets] if with_velocities else [[]] * len(targets)
    return validate_trajectory(ARM_JOINT_NAMES, times, [list(t) for t in targets], velocities,
                               [[]] * len(targets), world.kinematics.limits)


def offset_posture(delta):
    return np.array(READY_POSTURE) + np.array(delta)


def start(world, trajectory, tolerances=None, start_time=None):
    controller = world.controller
    return controller.start(trajectory, tolerances or controller.default_tolerances,
                            world.sim_time if start_time is None else start_time,
                            world.sim_time)


def run_until_done(world, execution, limit_s=20.0):
    for _ in range(round(limit_s * world.physics_hz)):
        if execution.done:
            return
        world.step()
    raise AssertionError(f"execution still {execution.status} after {limit_s} s")


@pytest.mark.parametrize("name", shipped_scenarios())
def test_resting_objects_stay_put(name):
    world = SimWorld(load_scenario(name))
    try:
        world.settle(0.5)
        before = world.object_poses()
        world.settle(5.0)
        after = world.object_poses()
    finally:
        world.close()
    for object_id, pose in before.items():
        moved = math.dist((pose.x, pose.y), (after[object_id].x, after[object_id].y))
        turned = abs(after[object_id].theta - pose.theta)
        assert moved < 5e-5, f"{name}/{object_id} drifted {moved * 1e3:.3f} mm"
        assert turned < 5e-4, f"{name}/{object_id} turned {turned:.4f} rad"


def test_arm_holds_ready_posture_when_idle(world):
    world.settle(2.0)
    state = world.joint_state()
    np.testing.assert_allclose(state.positions, READY_POSTURE, atol=1e-4)
    assert np.abs(state.velocities).max() < 1e-3


def test_short_trajectory_is_tracked_below_a_millimetre(world):
    targets = [offset_posture([0.3, 0.2, -0.2, 0.3, 0.2, -0.2, 0.3]), READY_POSTURE]
    execution = start(world, joint_trajectory(world, targets, [1.5, 3.0]))
    run_until_done(world, execution)
    assert execution.status is ExecutionStatus.SUCCEEDED, execution.error_string
    assert execution.tool_rms_error < 1e-3
    assert execution.tool_error_max < 2e-3
    np.testing.assert_allclose(world.joint_state().positions, READY_POSTURE, atol=0.01)


def test_pushing_slides_the_object_along_the_push(world):
    world.settle(3.0)      # long enough for the resting eraser to fall asleep
    eraser_before = world.object_poses()["eraser"]
    execution = start(world, push_trajectory(world.kinematics))
    run_until_done(world, execution)
    assert execution.status is ExecutionStatus.SUCCEEDED, execution.error_string
    assert execution.tool_rms_error < 1e-3
    eraser_after = world.object_poses()["eraser"]
    # The ball pushes the -y face towards +y by about 8 cm (it starts 2 cm away from it).
    assert 0.06 < eraser_after.y - eraser_before.y < 0.11
    assert abs(eraser_after.x - eraser_before.x) < 0.02
    # Still lying flat: its top is where it was.
    assert world.visual_state().body_poses["eraser"][0][2] == pytest.approx(0.015, abs=1e-3)


def test_new_goal_preempts_and_the_reference_stays_continuous(world):
    first = start(world, joint_trajectory(world, [offset_posture([0.6, 0, 0, 0, 0, 0, 0])],
                                          [3.0]))
    world.settle(1.0)
    desired_before = world.controller.desired.positions.copy()
    second = start(world, joint_trajectory(world, [READY_POSTURE], [2.0]))
    assert first.status is ExecutionStatus.PREEMPTED
    assert first.error_code is TrajectoryErrorCode.PREEMPTED
    world.step()
    step_change = np.abs(world.controller.desired.positions - desired_before).max()
    assert step_change < 0.6 / 3.0 * 2 / world.physics_hz * 2   # within a step of motion
    run_until_done(world, second)
    assert second.status is ExecutionStatus.SUCCEEDED


def test_cancel_stops_the_arm_where_it_is(world):
    execution = start(world, joint_trajectory(world, [offset_posture([0.6, 0, 0, 0, 0, 0, 0])],
                                              [3.0]))
    world.settle(1.5)
    world.controller.cancel(execution)
    assert execution.status is ExecutionStatus.CANCELED
    held = world.controller.desired.positions.copy()
    world.settle(1.0)
    state = world.joint_state()
    assert np.abs(state.velocities).max() < 1e-3
    np.testing.assert_allclose(state.positions, held, atol=1e-3)
    assert 0.1 < held[0] - READY_POSTURE[0] < 0.5     # stopped part-way


def test_path_tolerance_violation_aborts_and_holds(world):
    tight = Tolerances.uniform(path_position=1e-6, path_velocity=0.0, goal_position=0.01,
                               goal_velocity=0.01, goal_time=1.0)
    execution = start(world, joint_trajectory(world, [offset_posture([0.5, 0, 0, 0, 0, 0, 0])],
                                              [1.0]), tolerances=tight)
    run_until_done(world, execution)
    assert execution.status is ExecutionStatus.ABORTED
    assert execution.error_code is TrajectoryErrorCode.PATH_TOLERANCE_VIOLATED
    assert "panda_joint" in execution.error_string
    world.settle(1.0)
    assert np.abs(world.joint_state().velocities).max() < 1e-3


def test_goal_tolerance_violation_is_reported(world):
    impossible = Tolerances.uniform(path_position=0.1, path_velocity=0.0, goal_position=1e-9,
                                    goal_velocity=1e-9, goal_time=0.01)
    execution = start(world, joint_trajectory(world, [offset_posture([0.3, 0, 0, 0, 0, 0, 0])],
                                              [1.0]), tolerances=impossible)
    run_until_done(world, execution)
    assert execution.error_code is TrajectoryErrorCode.GOAL_TOLERANCE_VIOLATED


def test_trajectory_that_already_ended_is_refused(world):
    world.settle(3.0)
    with pytest.raises(TrajectoryError) as caught:
        start(world, joint_trajectory(world, [READY_POSTURE], [1.0]), start_time=0.5)
    assert caught.value.code is TrajectoryErrorCode.OLD_HEADER_TIMESTAMP


def test_disturb_moves_the_object_by_the_offset(world):
    world.settle(3.0)
    before = world.object_poses()["eraser"]
    after = world.disturb_object("eraser", 0.02, -0.01, 0.3)
    assert (after.x, after.y) == pytest.approx((before.x + 0.02, before.y - 0.01), abs=1e-9)
    world.settle(1.0)
    settled = world.object_poses()["eraser"]
    assert math.dist((settled.x, settled.y), (after.x, after.y)) < 5e-4
    assert angle_difference_modulo_symmetry(settled.theta, before.theta + 0.3, 2) == \
        pytest.approx(0.0, abs=5e-3)


def test_an_idle_scene_looks_the_same_and_a_moved_one_does_not(world):
    """The sim node reuses the last frame for a scene that looks like it (looks_like)."""
    world.settle(3.0)
    resting = world.visual_state()
    world.settle(2.0)
    assert resting.looks_like(world.visual_state())
    world.disturb_object("eraser", 0.001, 0.0, 0.0)
    assert not resting.looks_like(world.visual_state())
    moved_arm = dataclasses.replace(resting, joint_positions=tuple(
        np.add(resting.joint_positions, [0.0, 1e-3, 0, 0, 0, 0, 0])))
    assert not resting.looks_like(moved_arm)


@pytest.mark.parametrize("object_id, offset, reason", [
    ("stapler", (0.01, 0.0, 0.0), "unknown object 'stapler'"),
    ("hole_punch", (0.01, 0.0, 0.0), "fixed obstacle"),
    ("eraser", (0.0, -0.2, 0.0), "off the table"),
    ("eraser", (math.nan, 0.0, 0.0), "finite"),
])
def test_bad_disturbances_are_refused(world, object_id, offset, reason):
    with pytest.raises(SimWorldError, match=reason):
        world.disturb_object(object_id, *offset)


def test_load_scenario_restores_initial_poses(world):
    initial = {spec.id: spec.pose for spec in world.scenario.objects}
    world.disturb_object("eraser", 0.03, 0.03, 0.0)
    world.load_scenario(world.scenario)
    for object_id, pose in world.object_poses().items():
        assert math.dist((pose.x, pose.y), (initial[object_id].x, initial[object_id].y)) < 1e-6
    np.testing.assert_allclose(world.joint_state().positions, READY_POSTURE, atol=1e-9)


CAMERA_TEST_SCENARIO = {
    "format": 1, "name": "camera_test",
    "table": {"center": [0.45, 0.0], "size": [0.34, 0.52]},
    "objects": [{"id": "eraser", "class": "eraser", "pose": [0.35, 0.16, 0.3]},
                {"id": "scale", "class": "scale", "pose": [0.52, -0.17, -0.2]},
                {"id": "plate", "class": "plate", "pose": [0.5, 0.1, 0.0]}],
    "objective": {"terms": [{"type": "spread", "weight": 1.0}]},
}


@pytest.fixture(scope="module")
def camera_world():
    sim = SimWorld(parse_scenario(CAMERA_TEST_SCENARIO, "camera_test"))  # arm out of view
    sim.settle(1.0)     # objects start 0.5 mm above the table
    yield sim
    sim.close()


def test_arm_starts_out_of_the_cameras_view(camera_world):
    """By default the arm waits in OBSERVE_POSTURE, where no pixel shows it."""
    np.testing.assert_allclose(camera_world.joint_state().positions, OBSERVE_POSTURE, atol=1e-3)
    frame = camera_world.render()
    tallest = max(spec.height for spec in camera_world.scenario.objects)
    assert frame.depth.min() > camera_world.camera.position[2] - tallest - 1e-3


def test_camera_sees_object_tops_where_the_intrinsics_project_them(camera_world):
    """The top face of each object (found by its depth) is centred on the pixel the camera model
    predicts for the centre of that face, to a small fraction of a pixel (~1.2 mm per pixel)."""
    frame = camera_world.render()
    camera = camera_world.camera
    assert frame.rgb.shape == (camera.height, camera.width, 3) and frame.rgb.dtype == np.uint8
    assert frame.depth.shape == (camera.height, camera.width)
    assert frame.depth.dtype == np.float32
    for object_id, pose in camera_world.object_poses().items():
        spec = camera_world.object_spec(object_id)
        top_depth = camera.position[2] - spec.height
        predicted = camera.project_world_points(np.array([[pose.x, pose.y, spec.height]]))[0]
        rows, columns = np.nonzero(np.abs(frame.depth - top_depth) < 5e-4)
        near = (np.abs(columns - predicted[0]) < 100) & (np.abs(rows - predicted[1]) < 100)
        centroid = np.array([columns[near].mean(), rows[near].mean()])
        np.testing.assert_allclose(centroid, predicted, atol=0.15, err_msg=object_id)
        footprint_area = (math.pi / 4.0 if spec.shape == "cylinder" else 1.0) * (
            spec.length * spec.width) * (camera.focal_length_px / top_depth) ** 2
        assert near.sum() == pytest.approx(footprint_area, rel=0.01), object_id


def test_depth_is_metric_along_the_optical_axis(camera_world):
    frame = camera_world.render()
    camera = camera_world.camera
    table_pixel = camera.project_world_points(np.array([[0.60, 0.0, 0.0]]))[0].round().astype(int)
    assert frame.depth[table_pixel[1], table_pixel[0]] == pytest.approx(camera.position[2],
                                                                        abs=1e-4)


def test_render_worker_draws_the_same_image(camera_world):
    worker = RenderWorker(camera_world.scenario, camera_world.camera)
    try:
        remote = worker.render(camera_world.visual_state())
    finally:
        worker.close()
    local = camera_world.render()
    assert remote.sim_time == local.sim_time
    assert np.mean(np.abs(remote.rgb.astype(int) - local.rgb.astype(int))) < 0.5
    np.testing.assert_allclose(remote.depth, local.depth, atol=1e-4)


def test_render_worker_closes_with_a_frame_in_flight(camera_world):
    """A finished frame waits in the pipe and blocks the worker until it is read: closing must
    read it, or the worker never sees "stop" and is killed (a sim_node slow to end on SIGTERM)."""
    worker = RenderWorker(camera_world.scenario, camera_world.camera)
    worker.request(camera_world.visual_state())
    assert worker._connection.poll(60.0)           # rendered, not yet collected
    worker.close()
    assert worker._process.exitcode == 0
