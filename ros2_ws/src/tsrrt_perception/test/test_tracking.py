"""Tracker: identities, symmetry unwrap, statuses under occlusion/absence, settling."""

import math

import numpy as np
import pytest

from tsrrt_common.geometry import Pose2D, box_corners, wrap_angle
from tsrrt_common.object_classes import ObjectClass
from tsrrt_common.scenario import load_scenario
from tsrrt_perception.segmentation import Detection, HeightImage
from tsrrt_perception.tracking import (
    ExpectedObject,
    ObjectTracker,
    TrackerParams,
    TrackStatus,
    expected_objects,
)


def detection(cls: ObjectClass, x: float, y: float, theta: float = 0.0,
              occluded: bool = False, truncated: bool = False) -> Detection:
    """A detection as segmentation reports it: box headings only known modulo a half turn."""
    if cls.symmetry:
        theta = wrap_angle(theta * cls.symmetry / 2.0) * 2.0 / cls.symmetry  # into one period
    return Detection(Pose2D(x, y, theta), cls.name, cls.shape, cls.length, cls.width,
                     cls.height, cls.symmetry, 0.0, occluded, truncated, 4000)


def empty_frame(camera_view) -> HeightImage:
    return HeightImage(np.zeros((camera_view.height, camera_view.width), np.float32),
                       camera_view, 0.0)


def frame_with_block(camera_view, footprint: np.ndarray, height: float) -> HeightImage:
    heights = np.zeros((camera_view.height, camera_view.width), np.float32)
    polygon = np.round(camera_view.world_to_pixels(
        np.column_stack([footprint, np.full(len(footprint), height)]))).astype(int)
    u0, v0 = polygon.min(axis=0)
    u1, v1 = polygon.max(axis=0)
    heights[v0:v1 + 1, u0:u1 + 1] = height
    return HeightImage(heights, camera_view, 0.0)


def frame_with_object(camera_view, cls: ObjectClass, x: float, y: float) -> HeightImage:
    """A frame whose depth shows an object segmentation missed (its colour, say)."""
    footprint = box_corners(cls.length, cls.width) + np.array([x, y])
    return frame_with_block(camera_view, footprint, cls.height)


def by_id(tracker: ObjectTracker, frame_age: float | None = None):
    return {e.id: e for e in tracker.estimates(frame_age)}


@pytest.mark.parametrize("start", [math.pi / 2 - 0.1, -math.pi / 2 + 0.1])
def test_box_heading_turns_through_a_quarter_turn_without_jumping(classes, camera_view, start):
    eraser = classes["eraser"]
    tracker = ObjectTracker(classes)
    direction = 1.0 if start > 0 else -1.0
    reported = []
    for step in range(11):
        truth = start + direction * 0.02 * step
        tracker.update([detection(eraser, 0.45, 0.0, truth)], 0.1 * step, empty_frame(camera_view))
        reported.append(by_id(tracker)["eraser_1"].pose.theta)
    np.testing.assert_allclose(np.diff(reported), direction * 0.02, atol=1e-9)


def test_square_heading_unwraps_modulo_a_quarter_turn(camera_view):
    square = ObjectClass("tile", "box", 0.1, 0.1, 0.01, 4, 0.01)
    tracker = ObjectTracker({"tile": square})
    reported = []
    for step in range(12):
        tracker.update([detection(square, 0.45, 0.0, 0.7 + 0.02 * step)], 0.1 * step,
                       empty_frame(camera_view))
        reported.append(by_id(tracker)["tile_1"].pose.theta)
    np.testing.assert_allclose(np.diff(reported), 0.02, atol=1e-9)


def test_disc_heading_never_changes(classes, camera_view):
    tracker = ObjectTracker(classes)
    for step, theta in enumerate([0.0, 1.0, -2.0]):
        tracker.update([detection(classes["plate"], 0.45, 0.0, theta)], step * 0.1,
                       empty_frame(camera_view))
    assert by_id(tracker)["plate_1"].pose.theta == 0.0


def test_same_class_neighbours_keep_their_ids_whatever_the_detection_order(classes,
                                                                          camera_view):
    plate = classes["plate"]
    tracker = ObjectTracker(classes)
    for step in range(30):
        a = detection(plate, 0.40 + 0.003 * step, -0.055)
        b = detection(plate, 0.40 + 0.003 * step, 0.055)
        tracker.update([b, a] if step % 2 else [a, b], 0.1 * step, empty_frame(camera_view))
        estimates = by_id(tracker)
        assert estimates["plate_1"].pose.y == -0.055 and estimates["plate_2"].pose.y == 0.055


def test_expected_objects_name_detections_by_class_and_initial_pose(classes, camera_view):
    expected = [ExpectedObject("dinner", "plate", Pose2D(0.40, 0.15, 0.0)),
                ExpectedObject("side", "plate", Pose2D(0.50, -0.15, 0.0)),
                ExpectedObject("plate_1", "plate", Pose2D(0.35, 0.0, 0.0)),
                ExpectedObject("tray", "platter", Pose2D(0.45, 0.0, 2.0))]
    tracker = ObjectTracker(classes, expected=expected)
    platter = classes["platter"]
    tracker.update([detection(classes["plate"], 0.51, -0.14), detection(platter, 0.45, 0.0,
                                                                         2.0 - math.pi),
                    detection(classes["plate"], 0.41, 0.16)], 0.0, empty_frame(camera_view))
    estimates = by_id(tracker)
    assert estimates["dinner"].pose.x == 0.41 and estimates["side"].pose.x == 0.51
    assert estimates["tray"].pose.theta == pytest.approx(2.0)    # unwrapped toward the scenario
    assert estimates["plate_1"].status is TrackStatus.LOST      # expected but not seen yet
    tracker.update([detection(classes["plate"], 0.41, 0.16), detection(classes["plate"], 0.51,
                                                                       -0.14),
                    detection(platter, 0.45, 0.0, 2.0), detection(classes["plate"], 0.3, 0.0),
                    detection(classes["plate"], 0.55, 0.1)], 0.1, empty_frame(camera_view))
    estimates = by_id(tracker)
    assert estimates["plate_1"].status is TrackStatus.TRACKED
    assert estimates["plate_1"].pose.x == 0.3
    assert estimates["plate_2"].pose.x == 0.55                   # a new one, not plate_1 again


def test_a_scenario_obstacle_is_named_after_the_file(classes, camera_view):
    scenario = load_scenario("obstacle")
    tracker = ObjectTracker(classes, expected=expected_objects(scenario))
    punch = scenario.obstacles[0]
    events = tracker.update([detection(classes[punch.object_class], punch.pose.x, punch.pose.y,
                                       punch.pose.theta)], 0.0, empty_frame(camera_view))
    assert by_id(tracker)[punch.id].status is TrackStatus.TRACKED
    assert events == [f"{punch.id} first seen at ({punch.pose.x:.3f}, {punch.pose.y:.3f})"]


def test_covered_object_is_occluded_with_its_last_pose_then_reacquired(classes, camera_view):
    eraser = classes["eraser"]
    tracker = ObjectTracker(classes)
    tracker.update([detection(eraser, 0.45, 0.05, 0.3)], 0.0, empty_frame(camera_view))
    arm = box_corners(0.10, 0.10) + np.array([0.45, 0.05])
    tracker.update([detection(eraser, 0.46, 0.05, 0.3, occluded=True)], 0.1,
                   frame_with_block(camera_view, arm, 0.3))
    state = by_id(tracker)["eraser_1"]
    assert state.status is TrackStatus.OCCLUDED
    assert (state.pose.x, state.pose.y) == (0.45, 0.05)       # never the partial view's pose
    tracker.update([detection(eraser, 0.53, 0.05, 0.35)], 0.2, empty_frame(camera_view))
    state = by_id(tracker)["eraser_1"]
    assert state.status is TrackStatus.TRACKED and state.pose.x == 0.53


def test_plates_pushed_together_keep_their_ids_while_the_arm_still_hides_one(classes,
                                                                              camera_view):
    """A push moves plate_1 5 cm into plate_2, which moves 5 cm on. While the arm still covers
    plate_2, the one detection is as close to plate_2's last pose as to plate_1's: a tie must not
    decide whose it is. Once both are seen, each gets its own."""
    plate = classes["plate"]
    tracker = ObjectTracker(classes)
    tracker.update([detection(plate, 0.40, 0.0), detection(plate, 0.50, 0.0)], 0.0,
                   empty_frame(camera_view))
    arm = box_corners(0.25, 0.12) + np.array([0.45, 0.0])
    tracker.update([], 2.0, frame_with_block(camera_view, arm, 0.3))
    assert {e.status for e in by_id(tracker).values()} == {TrackStatus.OCCLUDED}
    still_covering_plate_2 = frame_with_block(
        camera_view, box_corners(0.12, 0.12) + np.array([0.55, 0.0]), 0.3)
    plate_1_seen = frame_with_object(camera_view, plate, 0.45, 0.0)
    frame = HeightImage(np.maximum(still_covering_plate_2.heights, plate_1_seen.heights),
                        camera_view, 0.0)
    events = tracker.update([detection(plate, 0.45, 0.0)], 4.0, frame)
    estimates = by_id(tracker)
    assert estimates["plate_1"].pose.x == 0.40 and estimates["plate_2"].pose.x == 0.50
    assert list(estimates) == ["plate_1", "plate_2"] and events == []
    tracker.update([detection(plate, 0.55, 0.0), detection(plate, 0.45, 0.0)], 6.0,
                   empty_frame(camera_view))
    estimates = by_id(tracker)
    assert estimates["plate_1"].pose.x == 0.45 and estimates["plate_2"].pose.x == 0.55


def test_lost_objects_take_back_the_detections_of_least_total_distance(classes, camera_view):
    """Two plates bumped out of their places at once: plate_2's old place is nearest to both new
    detections, but handing it the first one would give plate_1 the other, 12 cm away."""
    plate = classes["plate"]
    tracker = ObjectTracker(classes)
    tracker.update([detection(plate, 0.30, 0.0), detection(plate, 0.45, 0.0)], 0.0,
                   empty_frame(camera_view))
    tracker.update([], 0.1, empty_frame(camera_view))
    assert {e.status for e in by_id(tracker).values()} == {TrackStatus.LOST}
    events = tracker.update([detection(plate, 0.40, 0.2), detection(plate, 0.44, 0.2)], 0.2,
                            empty_frame(camera_view))
    estimates = by_id(tracker)
    assert estimates["plate_1"].pose.x == 0.40 and estimates["plate_2"].pose.x == 0.44
    assert sorted(events) == ["plate_1 found again 224 mm from where it was lost, at "
                              "(0.400, 0.200)",
                              "plate_2 found again 200 mm from where it was lost, at "
                              "(0.440, 0.200)"]


def test_identity_changes_are_reported_with_their_reason(classes, camera_view):
    remote = classes["remote"]
    tracker = ObjectTracker(classes, expected=[ExpectedObject("tv", "remote",
                                                              Pose2D(0.45, 0.0, 0.0))])
    assert tracker.update([detection(remote, 0.45, 0.01)], 0.0, empty_frame(camera_view)) \
        == ["tv first seen at (0.450, 0.010)"]
    assert tracker.update([], 0.1, empty_frame(camera_view)) \
        == ["tv lost at (0.450, 0.010): 100 % of its footprint is bare table"]
    assert tracker.update([detection(remote, 0.45, 0.2), detection(remote, 0.3, 0.2)], 0.2,
                          empty_frame(camera_view)) \
        == ["tv found again 190 mm from where it was lost, at (0.450, 0.200)",
            "remote_1: new object at (0.300, 0.200)"]


@pytest.mark.parametrize("frame_interval, same_track", [(0.1, False), (5.0, True)])
def test_push_between_sparse_frames_keeps_the_id(classes, camera_view, frame_interval,
                                                 same_track):
    """At 10 frames per wall second a fast simulation may push an object 6 cm between two frames
    seconds of simulated time apart: it is the same object. Frames 0.1 s apart bound it to 5 cm,
    so while depth still sees something at the old place, the detection is another object."""
    eraser = classes["eraser"]
    tracker = ObjectTracker(classes)
    tracker.update([detection(eraser, 0.45, 0.0)], 0.0, empty_frame(camera_view))
    tracker.update([detection(eraser, 0.51, 0.0)], frame_interval,
                   frame_with_object(camera_view, eraser, 0.45, 0.0))
    estimates = by_id(tracker)
    assert (estimates["eraser_1"].status is TrackStatus.TRACKED) == same_track
    assert ("eraser_2" in estimates) != same_track


def test_object_that_left_a_bare_place_keeps_its_id_where_it_went(classes, camera_view):
    """A bump (or a scenario reload) moves a plate 20 cm between frames: its old place shows the
    bare table, so it is gone from there at once and the new detection takes its id back."""
    plate = classes["plate"]
    tracker = ObjectTracker(classes)
    tracker.update([detection(plate, 0.45, 0.0)], 0.0, empty_frame(camera_view))
    tracker.update([detection(plate, 0.45, 0.2)], 0.1, empty_frame(camera_view))
    estimates = by_id(tracker)
    assert list(estimates) == ["plate_1"]
    assert estimates["plate_1"].status is TrackStatus.TRACKED
    assert (estimates["plate_1"].pose.x, estimates["plate_1"].pose.y) == (0.45, 0.2)


def test_object_whose_place_is_bare_is_lost_at_once(classes, camera_view):
    tracker = ObjectTracker(classes)
    tracker.update([detection(classes["remote"], 0.45, 0.0)], 0.0, empty_frame(camera_view))
    tracker.update([], 0.1, empty_frame(camera_view))
    assert by_id(tracker)["remote_1"].status is TrackStatus.LOST


def test_unseen_object_is_stale_then_lost(classes, camera_view):
    params = TrackerParams(lost_timeout=1.0)
    tracker = ObjectTracker(classes, params)
    remote = classes["remote"]
    tracker.update([detection(remote, 0.45, 0.0)], 0.0, empty_frame(camera_view))
    missed = frame_with_object(camera_view, remote, 0.45, 0.0)
    tracker.update([], 0.5, missed)
    assert by_id(tracker)["remote_1"].status is TrackStatus.STALE
    tracker.update([], 1.5, missed)
    assert by_id(tracker)["remote_1"].status is TrackStatus.LOST


def test_object_leaving_the_view_is_lost(classes, camera_view):
    tracker = ObjectTracker(classes)
    edge_y = camera_view.pixels_to_plane(np.array([[2.0, 240.0]]), 0.02)[0, 1]
    tracker.update([detection(classes["remote"], 0.45, edge_y - 0.03)], 0.0,
                   empty_frame(camera_view))
    tracker.update([detection(classes["remote"], 0.45, edge_y, truncated=True)], 0.1,
                   empty_frame(camera_view))
    assert by_id(tracker)["remote_1"].status is TrackStatus.LOST


def test_poses_go_stale_when_frames_stop(classes, camera_view):
    tracker = ObjectTracker(classes, TrackerParams(stale_timeout=0.5))
    tracker.update([detection(classes["scale"], 0.45, 0.0)], 10.0, empty_frame(camera_view))
    assert by_id(tracker, frame_age=0.4)["scale_1"].status is TrackStatus.TRACKED
    assert by_id(tracker, frame_age=0.6)["scale_1"].status is TrackStatus.STALE


def test_settled_only_after_the_window_of_stillness(classes, camera_view):
    params = TrackerParams(settle_window=0.3, settle_speed=0.005)
    tracker = ObjectTracker(classes, params)
    x = 0.40
    settled = []
    for step in range(12):
        if step < 5:
            x += 0.01                                     # being pushed at 10 cm/s
        tracker.update([detection(classes["eraser"], x, 0.0),
                        detection(classes["plate"], 0.5, 0.15)], 0.1 * step,
                       empty_frame(camera_view))
        settled.append(tracker.settled())
    # Still from step 4 on (t=0.4); the 0.3 s window is first entirely still at t=0.7.
    assert settled == [False] * 7 + [True] * 5


def test_settling_needs_every_object_in_view(classes, camera_view):
    tracker = ObjectTracker(classes)
    for step in range(6):
        tracker.update([detection(classes["eraser"], 0.4, 0.0),
                        detection(classes["plate"], 0.5, 0.15)], 0.1 * step,
                       empty_frame(camera_view))
    assert tracker.settled()
    tracker.update([detection(classes["eraser"], 0.4, 0.0)], 0.6,
                   frame_with_object(camera_view, classes["plate"], 0.5, 0.15))
    assert not tracker.settled()
    assert tracker.unsettled_reasons() == ["plate_1 stale"]
