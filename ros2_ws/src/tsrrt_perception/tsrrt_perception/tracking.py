"""Stable identities, symmetry-consistent headings and honest status for detected objects.

Each frame's valid detections are assigned to known objects by predicted position and class
(Hungarian assignment); a detection that an unseen object of its class would explain almost as
well waits for a frame that tells them apart (two identical plates pushed together, one still
under the arm, must not swap names on a tie). Headings are unwrapped modulo each class's symmetry,
so a box turning by a degree never reads as a jump of pi. An object that is not seen keeps its
last pose but is marked: OCCLUDED when something much higher stands over its last footprint (the
arm), LOST when its footprint leaves the view or it has been gone too long, STALE otherwise; a
wrong pose is never reported as TRACKED. Settling (all objects seen and still over a window) lets
a learner measure a push's displacement.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import TypeVar

import numpy as np
from scipy.optimize import linear_sum_assignment

from tsrrt_common.geometry import Pose2D, angle_difference_modulo_symmetry, footprint_polygon
from tsrrt_common.object_classes import ObjectClass, lookup_class
from tsrrt_common.scenario import Scenario
from tsrrt_perception.segmentation import Detection, HeightImage

_NO_MATCH = 1e6


class TrackStatus(IntEnum):
    """Same values as tsrrt_interfaces/ObjectState STATUS_*."""

    TRACKED = 0
    OCCLUDED = 1
    STALE = 2
    LOST = 3


@dataclass(frozen=True)
class ExpectedObject:
    """An object the scenario says is on the table, with its initial pose, to name detections."""

    id: str
    object_class: str
    pose: Pose2D


@dataclass(frozen=True)
class TrackerParams:
    gate_tracked: float = 0.05          # m an object seen last frame may move by the next
    gate_unseen: float = 0.15           # m an occluded or stale object may have moved meanwhile
    # s (frame stamps) within which gate_tracked applies; frames further apart (a simulation
    # running many times faster than real time, 10 frames per wall second) may miss a whole
    # 5 cm push, so a tracked object is then gated like an unseen one.
    tracked_gate_interval: float = 0.5
    angle_cost: float = 0.01            # m of assignment cost per radian of heading mismatch
    # m: a detection that an unmatched track of its class could explain almost as well (a push
    # moved two touching plates, the arm still hides one) is left unassigned for the frame,
    # rather than letting a tie decide which identity it gets
    ambiguity_margin: float = 0.02
    occlusion_margin: float = 0.01      # m above an object's top that counts as covering it
    occlusion_min_fraction: float = 0.02  # share of the footprint that must be covered
    # share of an unseen object's footprint that must show the bare table for it to have left
    # (LOST at once, so that a same-class detection elsewhere takes its id back)
    vacated_min_fraction: float = 0.9
    lost_timeout: float = 5.0           # s unseen (and not covered) after which it is LOST
    stale_timeout: float = 1.0          # s without a new frame (caller's clock): poses STALE
    settle_window: float = 0.3          # s over which an object must be still to be settled
    settle_speed: float = 0.005         # m/s below which an object is still
    settle_angular_speed: float = 0.05  # rad/s below which an object is still


@dataclass(frozen=True)
class ObjectEstimate:
    """What perception reports about one object (mirrors tsrrt_interfaces/ObjectState)."""

    id: str
    object_class: str
    shape: str
    pose: Pose2D
    length: float
    width: float
    height: float
    symmetry: int
    confidence: float
    status: TrackStatus
    last_seen: float | None      # stamp (s) of the last frame it was seen in; None: never


class _Track:
    """Mutable per-object state kept between frames."""

    def __init__(self, object_id: str, cls: ObjectClass, pose: Pose2D,
                 detection: Detection | None, stamp: float | None) -> None:
        self.id = object_id
        self.cls = cls
        self.pose = pose
        self.velocity = np.zeros(2)
        self.length, self.width, self.height = cls.length, cls.width, cls.height
        self.observations = 0
        self.confidence = 0.0
        self.last_seen = stamp
        self.status = TrackStatus.LOST
        self.history: deque[tuple[float, float, float, float]] = deque(maxlen=200)
        if detection is not None and stamp is not None:
            self.observe(detection, stamp)

    def predicted_position(self, stamp: float) -> np.ndarray:
        position = np.array([self.pose.x, self.pose.y])
        if self.status is TrackStatus.TRACKED and self.last_seen is not None:
            position += self.velocity * min(stamp - self.last_seen, 0.5)
        return position

    def unwrap(self, theta: float) -> float:
        """The heading equivalent to theta under the symmetry that is closest to the last one."""
        if self.cls.symmetry == 0:
            return self.pose.theta
        return self.pose.theta + angle_difference_modulo_symmetry(theta, self.pose.theta,
                                                                  self.cls.symmetry)

    def observe(self, detection: Detection, stamp: float) -> None:
        theta = self.unwrap(detection.pose.theta)
        if self.status is TrackStatus.TRACKED and self.last_seen is not None \
                and stamp > self.last_seen:
            step = np.array([detection.pose.x - self.pose.x, detection.pose.y - self.pose.y])
            self.velocity = 0.5 * self.velocity + 0.5 * step / (stamp - self.last_seen)
        else:
            self.velocity = np.zeros(2)
            self.history.clear()    # settling needs an unbroken run of observations
        self.pose = Pose2D(detection.pose.x, detection.pose.y, theta)
        weight = 1.0 / min(self.observations + 1, 20)
        self.length += weight * (detection.length - self.length)
        self.width += weight * (detection.width - self.width)
        self.height += weight * (detection.height - self.height)
        self.observations += 1
        self.confidence = float(np.clip(1.0 - detection.class_error / self.cls.tolerance, 0.1, 1))
        self.last_seen = stamp
        self.status = TrackStatus.TRACKED
        self.history.append((stamp, self.pose.x, self.pose.y, self.pose.theta))

    def footprint(self) -> np.ndarray:
        return footprint_polygon(self.cls.shape, self.length, self.width, self.pose, disc_sides=12)


_Posed = TypeVar("_Posed", ExpectedObject, _Track)


def expected_objects(scenario: Scenario) -> list[ExpectedObject]:
    """What a scenario places on the table, objects and obstacles alike: a fixed obstacle is in
    view too, and is named after the file rather than as a new <class>_1."""
    return [ExpectedObject(o.id, o.object_class, o.pose)
            for o in (*scenario.objects, *scenario.obstacles)]


class ObjectTracker:
    """Keeps identities and statuses of tabletop objects across frames (ROS-free)."""

    def __init__(self, classes: dict[str, ObjectClass], params: TrackerParams | None = None,
                 expected: Sequence[ExpectedObject] = ()) -> None:
        """
        Args:
            classes: the class table.
            params: thresholds; defaults when None.
            expected: objects the scenario places, to name detections after (by class, closest
                to the scenario's initial pose); without them objects are named <class>_<n>.
        """
        self.classes = classes
        self.params = params or TrackerParams()
        for spec in expected:
            lookup_class(classes, spec.object_class)
        self.pending = list(expected)     # expected objects not seen yet
        self.tracks: list[_Track] = []
        self.last_frame: float | None = None

    # ------------------------------------------------------------------------------- update
    def update(self, detections: Sequence[Detection], stamp: float,
               height_image: HeightImage | None = None) -> list[str]:
        """Fold one frame's detections (taken at `stamp`, seconds) into the tracks.

        Returns:
            what changed about identities (an object first seen, lost and why, found again, a
            new id), one line each, for the node's log: these are what a wrong plan is traced to.
        """
        valid = [d for d in detections if d.pose_valid]
        active = [t for t in self.tracks if t.status is not TrackStatus.LOST]
        matched_tracks, unmatched = self._assign(active, valid, stamp)
        for track, detection in matched_tracks:
            track.observe(detection, stamp)
        seen = {id(track) for track, _ in matched_tracks}
        obstructions = [d for d in detections if not d.pose_valid]
        events = []
        for track in self.tracks:
            if id(track) not in seen and track.last_seen is not None \
                    and track.last_seen != stamp:
                was_lost = track.status is TrackStatus.LOST
                track.status, why = self._unseen_status(track, stamp, height_image, obstructions)
                if track.status is TrackStatus.LOST and not was_lost:
                    events.append(f"{track.id} lost at ({track.pose.x:.3f}, {track.pose.y:.3f}): "
                                  f"{why}")
        # After the statuses: an object that left its place (a bump, a scenario reload) is LOST
        # by now, and the detection where it went takes its id back.
        events += self._name_new(unmatched, stamp)
        self.last_frame = stamp
        return events

    def _assign(self, tracks: list[_Track], detections: list[Detection],
                stamp: float) -> tuple[list[tuple[_Track, Detection]], list[Detection]]:
        """Hungarian assignment within gates. Returns the pairs and the detections no track
        could explain; ambiguous detections are in neither."""
        if not tracks or not detections:
            return [], list(detections)
        cost = np.full((len(tracks), len(detections)), _NO_MATCH)
        for i, track in enumerate(tracks):
            predicted = track.predicted_position(stamp)
            recently_seen = (track.status is TrackStatus.TRACKED and track.last_seen is not None
                             and stamp - track.last_seen <= self.params.tracked_gate_interval)
            gate = self.params.gate_tracked if recently_seen else self.params.gate_unseen
            for j, detection in enumerate(detections):
                if detection.object_class != track.cls.name:
                    continue
                distance = float(np.hypot(detection.pose.x - predicted[0],
                                          detection.pose.y - predicted[1]))
                if distance > gate:
                    continue
                turn = abs(angle_difference_modulo_symmetry(detection.pose.theta, track.pose.theta,
                                                            track.cls.symmetry))
                cost[i, j] = distance + self.params.angle_cost * turn
        rows, cols = linear_sum_assignment(cost)
        kept = [(i, j) for i, j in zip(rows, cols, strict=True) if cost[i, j] < _NO_MATCH]
        assigned_rows = {i for i, _ in kept}
        unassigned_rows = [i for i in range(len(tracks)) if i not in assigned_rows]
        ambiguous = {j for i, j in kept
                     if any(cost[other, j] < cost[i, j] + self.params.ambiguity_margin
                            for other in unassigned_rows)}
        pairs = [(tracks[i], detections[j]) for i, j in kept if j not in ambiguous]
        used = {j for _, j in kept}
        return pairs, [d for j, d in enumerate(detections) if j not in used]

    def _name_new(self, detections: list[Detection], stamp: float) -> list[str]:
        """Start tracks for unmatched detections: expected ids first, then lost ones, then new."""
        events = []
        detections = sorted(detections, key=lambda d: (d.object_class, d.pose.x, d.pose.y))
        for class_name in sorted({d.object_class for d in detections}):
            cls = self.classes[class_name]
            of_class = [d for d in detections if d.object_class == class_name]
            expected = [e for e in self.pending if e.object_class == class_name]
            for spec, detection, _ in _closest_pairs(expected, of_class):
                start = Pose2D(spec.pose.x, spec.pose.y, spec.pose.theta)
                self.tracks.append(_Track(spec.id, cls, start, detection, stamp))
                self.pending.remove(spec)
                events.append(f"{spec.id} first seen at ({detection.pose.x:.3f}, "
                              f"{detection.pose.y:.3f})")
                of_class.remove(detection)
            lost = [t for t in self.tracks
                    if t.cls.name == class_name and t.status is TrackStatus.LOST]
            for track, detection, distance in _closest_pairs(lost, of_class):
                track.observe(detection, stamp)
                events.append(f"{track.id} found again {1000 * distance:.0f} mm from where it "
                              f"was lost, at ({detection.pose.x:.3f}, {detection.pose.y:.3f})")
                of_class.remove(detection)
            for detection in of_class:
                start = Pose2D(detection.pose.x, detection.pose.y,
                               angle_difference_modulo_symmetry(detection.pose.theta, 0.0,
                                                                cls.symmetry))
                track = _Track(self._new_id(class_name), cls, start, detection, stamp)
                self.tracks.append(track)
                events.append(f"{track.id}: new object at ({detection.pose.x:.3f}, "
                              f"{detection.pose.y:.3f})")
        return events

    def _new_id(self, class_name: str) -> str:
        taken = {t.id for t in self.tracks} | {e.id for e in self.pending}
        n = 1
        while f"{class_name}_{n}" in taken:
            n += 1
        return f"{class_name}_{n}"

    def _unseen_status(self, track: _Track, stamp: float, height_image: HeightImage | None,
                       obstructions: list[Detection]) -> tuple[TrackStatus, str]:
        """Why a known object was not seen: covered, out of view, briefly missing, or gone."""
        if track.status is TrackStatus.LOST:
            return TrackStatus.LOST, "still lost"
        footprint = track.footprint()
        if height_image is not None:
            if height_image.visible_fraction(footprint, track.height) < 1.0:
                return TrackStatus.LOST, "its footprint left the camera's view"
            covered = height_image.covered_fraction(footprint, track.height,
                                                    self.params.occlusion_margin)
            if covered >= self.params.occlusion_min_fraction:
                return TrackStatus.OCCLUDED, "covered"
            bare = height_image.bare_fraction(footprint, track.height, 0.5 * track.height)
            if bare >= self.params.vacated_min_fraction:
                return TrackStatus.LOST, f"{100 * bare:.0f} % of its footprint is bare table"
        for detection in obstructions:
            near = math.hypot(detection.pose.x - track.pose.x, detection.pose.y - track.pose.y)
            if near <= self.params.gate_unseen and (detection.occluded or detection.truncated
                                                    or detection.object_class is None):
                if detection.truncated:
                    return TrackStatus.LOST, "it is cut by the image border"
                return TrackStatus.OCCLUDED, "next to an obstruction"
        if stamp - track.last_seen > self.params.lost_timeout:
            return TrackStatus.LOST, f"unseen for {stamp - track.last_seen:.1f} s"
        return TrackStatus.STALE, "missing from this frame"

    # ------------------------------------------------------------------------------ queries
    def estimates(self, frame_age: float | None = None) -> list[ObjectEstimate]:
        """Every object known, sorted by id.

        Args:
            frame_age: seconds since the latest frame arrived, on the caller's clock (a node
                uses the wall clock, since a fast simulation delivers frames seconds of
                simulated time apart); beyond the stale timeout tracked poses are STALE.
        """
        frame_is_old = frame_age is not None and frame_age > self.params.stale_timeout
        result = []
        for track in self.tracks:
            status = track.status
            if status is TrackStatus.TRACKED and frame_is_old:
                status = TrackStatus.STALE
            confidence = {TrackStatus.TRACKED: 1.0, TrackStatus.OCCLUDED: 0.5,
                          TrackStatus.STALE: 0.5, TrackStatus.LOST: 0.0}[status] * track.confidence
            result.append(ObjectEstimate(
                track.id, track.cls.name, track.cls.shape, track.pose, track.length,
                track.width if track.cls.shape == "box" else track.length, track.height,
                track.cls.symmetry, confidence, status, track.last_seen))
        for spec in self.pending:
            cls = self.classes[spec.object_class]
            result.append(ObjectEstimate(spec.id, cls.name, cls.shape, spec.pose, cls.length,
                                         cls.width, cls.height, cls.symmetry, 0.0,
                                         TrackStatus.LOST, None))
        return sorted(result, key=lambda e: e.id)

    def settled(self, max_speed: float | None = None) -> bool:
        """Whether, in the latest frame, every object not lost was seen and has been still
        (speed below max_speed, default the settle speed) over the whole settle window."""
        if self.last_frame is None:
            return False
        max_speed = self.params.settle_speed if max_speed is None else max_speed
        start = self.last_frame - self.params.settle_window - 1e-6   # tolerate stamp rounding
        for track in self.tracks:
            if track.status is TrackStatus.LOST:
                continue
            if track.status is not TrackStatus.TRACKED or track.last_seen != self.last_frame:
                return False
            samples = np.array(track.history)
            if samples[0, 0] > start:
                return False
            recent = samples[samples[:, 0] >= start]
            drift = np.hypot(recent[:, 1] - recent[-1, 1], recent[:, 2] - recent[-1, 2]).max()
            turn = np.abs(recent[:, 3] - recent[-1, 3]).max()
            window = self.params.settle_window
            if drift > max_speed * window or turn > self.params.settle_angular_speed * window:
                return False
        return True

    def unsettled_reasons(self) -> list[str]:
        """Ids of the objects that keep the scene from being settled, with why (for messages)."""
        reasons = []
        for estimate in self.estimates():
            if estimate.status in (TrackStatus.OCCLUDED, TrackStatus.STALE):
                reasons.append(f"{estimate.id} {estimate.status.name.lower()}")
        return reasons


def _closest_pairs(candidates: list[_Posed],
                   detections: list[Detection]) -> list[tuple[_Posed, Detection, float]]:
    """(candidate, detection, distance) pairs of least total distance between candidate poses
    (expected objects or lost tracks) and detections: nearest-first greedy matching can hand
    two neighbours each other's identity."""
    if not candidates or not detections:
        return []
    cost = np.array([[math.hypot(d.pose.x - c.pose.x, d.pose.y - c.pose.y) for d in detections]
                     for c in candidates])
    rows, cols = linear_sum_assignment(cost)
    return [(candidates[i], detections[j], float(cost[i, j]))
            for i, j in zip(rows, cols, strict=True)]
