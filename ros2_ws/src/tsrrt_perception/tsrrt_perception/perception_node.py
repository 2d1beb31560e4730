"""ROS 2 node: overhead camera (colour + depth + CameraInfo) -> object states and markers.

Thin: colour and depth frames are paired by frame_pairing, their fields go through
image_conversion, the pairs through segmentation and tracking; this module only reads parameters
and fills messages. Object states are republished at a fixed wall-clock rate even when frames
come slower, with statuses aged accordingly.
"""

from __future__ import annotations

import ctypes
import threading
import time
from dataclasses import dataclass

import numpy as np
from builtin_interfaces.msg import Time as TimeMsg
from geometry_msgs.msg import Point
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.time import Time
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from tsrrt_common.errors import TsrrtError
from tsrrt_common.geometry import footprint_polygon
from tsrrt_common.object_classes import load_class_table
from tsrrt_common.ros_node import run_node
from tsrrt_common.scenario import load_scenario
from tsrrt_interfaces.msg import ObjectState, ObjectStateArray
from tsrrt_interfaces.srv import GetSettledObjects
from tsrrt_perception.camera_view import OVERHEAD_ORIENTATION_XYZW, CameraView
from tsrrt_perception.frame_pairing import ExactStampPairer
from tsrrt_perception.image_conversion import image_to_array
from tsrrt_perception.segmentation import (
    SegmentationParams,
    SegmentationResult,
    segment_objects,
)
from tsrrt_perception.tracking import (
    ExpectedObject,
    ObjectEstimate,
    ObjectTracker,
    TrackerParams,
    TrackStatus,
    expected_objects,
)

FRAME_ID = "world"
PAIRING_BUFFER = 10              # at most this many frames per stream wait for their partner
SKIP_LOG_PERIOD_S = 5.0          # the same reason for skipping frames is logged this often
STATUS_COLORS = {TrackStatus.TRACKED: (0.1, 0.9, 0.1), TrackStatus.OCCLUDED: (0.95, 0.8, 0.1),
                 TrackStatus.STALE: (0.95, 0.5, 0.1), TrackStatus.LOST: (0.9, 0.1, 0.1)}


def _stamp_key(stamp: TimeMsg) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def _same_image(first: Image, second: Image) -> bool:
    """Whether two images carry the same pixels (a byte comparison: 1 ms for a frame, against
    15-20 ms to segment it)."""
    return (first.encoding, first.width, first.height, first.step, first.is_bigendian) == \
        (second.encoding, second.width, second.height, second.step, second.is_bigendian) \
        and first.data == second.data


def _float_range(low: float, high: float, text: str) -> ParameterDescriptor:
    return ParameterDescriptor(description=text, floating_point_range=[
        FloatingPointRange(from_value=low, to_value=high, step=0.0)])


def _image_qos(reliability: str) -> QoSProfile:
    """Image subscription QoS. Reliable by default: over best effort, most 1-2 MB frames never
    arrive whole, even on one machine (Fast DDS, default or LARGE_DATA transports: 6-13 colour-
    depth pairs of 100 frames in 10 s; reliable: all of them)."""
    policies = {"reliable": ReliabilityPolicy.RELIABLE,
                "best_effort": ReliabilityPolicy.BEST_EFFORT}
    if reliability not in policies:
        raise TsrrtError(f"image_reliability must be one of {sorted(policies)}, got "
                         f"{reliability!r}")
    return QoSProfile(depth=2, reliability=policies[reliability])


@dataclass
class _SettleRequest:
    not_before: float            # sim time (s): only frames stamped at or after it count
    max_speed: float | None
    done: threading.Event
    result: list[ObjectEstimate] | None = None


class PerceptionNode(Node):
    def __init__(self) -> None:
        super().__init__("perception_node")
        self._declare_parameters()
        p = self.get_parameter
        self.camera_position = tuple(p("camera_position").value)
        self.camera_orientation = tuple(p("camera_orientation_xyzw").value)
        self.table_height = p("table_height").value
        self.segmentation_params = SegmentationParams(
            depth_threshold=p("depth_threshold").value,
            top_face_tolerance=p("top_face_tolerance").value,
            height_tolerance=p("height_tolerance").value,
            occluder_margin=p("occluder_margin").value,
            min_area_px=p("min_area_px").value)
        tracker_params = TrackerParams(
            stale_timeout=p("stale_timeout").value, lost_timeout=p("lost_timeout").value,
            settle_speed=p("settle_speed").value, settle_window=p("settle_window").value,
            settle_angular_speed=p("settle_angular_speed").value)
        self.classes = load_class_table()
        self.tracker = ObjectTracker(self.classes, tracker_params, self._expected_objects())

        self.lock = threading.Lock()
        self.camera: CameraView | None = None
        self.camera_problem: str | None = "no CameraInfo received yet"
        self._skip_logged: dict[str, float] = {}   # reason -> monotonic time it was logged
        self.pairer: ExactStampPairer[Image] = ExactStampPairer(PAIRING_BUFFER)  # colour, depth
        self.settle_requests: list[_SettleRequest] = []
        # (stamp, estimates) of the latest frame that was settled at the default speeds.
        self.latest_settled: tuple[float, list[ObjectEstimate]] | None = None
        self.last_publish = 0.0          # monotonic (wall) time of the last publication
        self.last_frame_arrival: float | None = None   # monotonic time of the last frame
        # camera model, colour, depth and segmentation of the last pair segmented
        self._last_segmented: tuple[CameraView, Image, Image, SegmentationResult] | None = None

        images = MutuallyExclusiveCallbackGroup()
        image_qos = _image_qos(p("image_reliability").value)
        self.create_subscription(Image, "/camera/image_raw", self._on_colour, image_qos,
                                 callback_group=images)
        self.create_subscription(Image, "/camera/depth/image_raw", self._on_depth, image_qos,
                                 callback_group=images)
        self.create_subscription(CameraInfo, "/camera/camera_info", self._on_camera_info,
                                 qos_profile_sensor_data, callback_group=images)
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.objects_pub = self.create_publisher(ObjectStateArray, "/perception/objects", reliable)
        self.markers_pub = self.create_publisher(MarkerArray, "/perception/markers", reliable)
        self.create_service(GetSettledObjects, "/perception/get_settled_objects",
                            self._on_get_settled, callback_group=ReentrantCallbackGroup())
        self.period = 1.0 / p("publish_rate").value
        # Own group: republishing must not wait behind a frame being segmented.
        self.create_timer(self.period / 2.0, self._on_timer,
                          callback_group=MutuallyExclusiveCallbackGroup(),
                          clock=Clock(clock_type=ClockType.STEADY_TIME))

    # --------------------------------------------------------------------------- parameters
    def _declare_parameters(self) -> None:
        declare = self.declare_parameter
        declare("camera_position", [0.45, 0.0, 0.9], ParameterDescriptor(
            description="optical centre of the camera in the world frame (x, y, z), metres"))
        declare("camera_orientation_xyzw", list(OVERHEAD_ORIENTATION_XYZW), ParameterDescriptor(
            description="orientation of the optical frame in the world frame, quaternion "
                        "(x, y, z, w); the default looks straight down, image up = world +x"))
        declare("table_height", 0.0, _float_range(-1.0, 2.0, "world z of the table top, metres"))
        declare("depth_threshold", 0.005, _float_range(
            0.001, 0.1, "height above the table from which a pixel belongs to an object, m"))
        declare("top_face_tolerance", 0.001, _float_range(
            0.0002, 0.02, "height difference within which a pixel is on an object's top face, m"))
        declare("height_tolerance", 0.003, _float_range(
            0.0005, 0.05, "difference between a top face's height and its class's within which "
                          "the face may be of that class, m"))
        declare("occluder_margin", 0.01, _float_range(
            0.002, 0.5, "height above an object's top that counts as something covering it, m"))
        declare("min_area_px", 150, ParameterDescriptor(
            description="smallest top face (pixels) taken for an object",
            integer_range=[IntegerRange(from_value=10, to_value=100000, step=1)]))
        declare("image_reliability", "reliable", ParameterDescriptor(
            description="QoS reliability of the image subscriptions: 'reliable' (what "
                        "tsrrt_sim offers) or 'best_effort' (for a camera driver publishing "
                        "sensor-data QoS)", read_only=True))
        declare("scenario", "", ParameterDescriptor(
            description="scenario name or path whose object and obstacle ids name the detections "
                        "(closest to their initial pose, by class); empty: <class>_<n>"))
        declare("scenario_seed", -1, ParameterDescriptor(
            description="seed for the scenario's random placements; -1 uses the file's",
            integer_range=[IntegerRange(from_value=-1, to_value=2**31 - 1, step=1)]))
        declare("stale_timeout", 1.0, _float_range(
            0.05, 60.0, "wall-clock seconds without a new frame after which poses are STALE"))
        declare("lost_timeout", 5.0, _float_range(
            0.1, 600.0, "seconds (frame stamps) an object may stay unseen, not covered, before "
                        "it is LOST"))
        declare("settle_speed", 0.005, _float_range(
            1e-5, 1.0, "m/s below which an object counts as still for a settled observation"))
        declare("settle_angular_speed", 0.05, _float_range(
            1e-5, 10.0, "rad/s below which an object counts as still"))
        declare("settle_window", 0.3, _float_range(
            0.0, 10.0, "seconds over which every object must be still to be settled"))
        declare("publish_rate", 10.0, _float_range(
            1.0, 100.0, "Hz at which object states are (re)published, wall clock"))

    def _expected_objects(self) -> list[ExpectedObject]:
        name = self.get_parameter("scenario").value
        if not name:
            return []
        seed = self.get_parameter("scenario_seed").value
        scenario = load_scenario(name, seed=None if seed < 0 else seed)
        return expected_objects(scenario)

    # ---------------------------------------------------------------------------- callbacks
    def _on_camera_info(self, msg: CameraInfo) -> None:
        try:
            camera = CameraView.from_camera_info(list(msg.k), msg.width, msg.height,
                                                 self.camera_position, self.camera_orientation)
        except TsrrtError as error:
            self.camera, self.camera_problem = None, str(error)
            self._skip(f"unusable CameraInfo: {error}")
            return
        if self.camera is None or not (np.array_equal(camera.intrinsics, self.camera.intrinsics)
                                       and (camera.width, camera.height)
                                       == (self.camera.width, self.camera.height)):
            self.camera, self.camera_problem = camera, None

    def _on_colour(self, msg: Image) -> None:
        self._pair(0, msg)

    def _on_depth(self, msg: Image) -> None:
        self._pair(1, msg)

    def _pair(self, stream: int, msg: Image) -> None:
        pair = self.pairer.add(stream, _stamp_key(msg.header.stamp), msg)
        if pair is not None:
            self._process(*pair)

    def _skip(self, reason: str) -> None:
        """Log why a frame is skipped: each distinct reason at once, then at most every
        SKIP_LOG_PERIOD_S (a logger throttle would hide a new reason behind an old one)."""
        now = time.monotonic()
        if now - self._skip_logged.get(reason, -SKIP_LOG_PERIOD_S) < SKIP_LOG_PERIOD_S:
            return
        self._skip_logged = {r: t for r, t in self._skip_logged.items()
                             if now - t < SKIP_LOG_PERIOD_S}
        self._skip_logged[reason] = now
        self.get_logger().warning(f"skipping frame: {reason}")

    def _process(self, colour_msg: Image, depth_msg: Image) -> None:
        if self.camera is None:
            self._skip(self.camera_problem or "no camera model")
            return
        previous = self._last_segmented
        if previous is not None and previous[0] is self.camera \
                and _same_image(previous[1], colour_msg) and _same_image(previous[2], depth_msg):
            # A still scene (the sim sends the same frame again): nothing new to segment.
            result = previous[3]
        else:
            result = self._segment(colour_msg, depth_msg)
            if result is None:
                return
            self._last_segmented = (self.camera, colour_msg, depth_msg, result)
        stamp = Time.from_msg(depth_msg.header.stamp).nanoseconds * 1e-9
        with self.lock:
            events = self.tracker.update(result.detections, stamp, result.height_image)
            self.last_frame_arrival = time.monotonic()
            self.latest_settled = ((stamp, self.tracker.estimates())
                                   if self.tracker.settled() else None)
            for request in self.settle_requests:
                if request.result is None and stamp >= request.not_before \
                        and self.tracker.settled(request.max_speed):
                    request.result = self.tracker.estimates()
                    request.done.set()
        for event in events:
            self.get_logger().info(event)
        self._publish()

    def _segment(self, colour_msg: Image, depth_msg: Image) -> SegmentationResult | None:
        """Objects seen in a colour-depth pair; None (with the reason logged) for an unusable
        pair."""
        try:
            rgb = image_to_array(colour_msg.encoding, colour_msg.width, colour_msg.height,
                                 colour_msg.step, bool(colour_msg.is_bigendian), colour_msg.data)
            depth = image_to_array(depth_msg.encoding, depth_msg.width, depth_msg.height,
                                   depth_msg.step, bool(depth_msg.is_bigendian), depth_msg.data)
        except TsrrtError as error:
            self._skip(str(error))
            return None
        if colour_msg.encoding not in ("rgb8", "bgr8"):
            self._skip(f"colour image has encoding {colour_msg.encoding!r}, expected rgb8 or bgr8")
            return None
        if colour_msg.encoding == "bgr8":
            rgb = rgb[:, :, ::-1]
        if depth_msg.encoding == "16UC1":
            depth = depth.astype(np.float32) * 0.001       # REP 118: millimetres
        elif depth_msg.encoding != "32FC1":
            self._skip(f"depth image has encoding {depth_msg.encoding!r}, expected 32FC1/16UC1")
            return None
        if rgb.shape[:2] != depth.shape:
            self._skip(f"colour {rgb.shape[1]}x{rgb.shape[0]} and depth "
                       f"{depth.shape[1]}x{depth.shape[0]} differ in size")
            return None
        try:
            return segment_objects(depth, self.camera, self.table_height, self.classes,
                                   self.segmentation_params, rgb)
        except TsrrtError as error:
            self._skip(str(error))
            return None

    def _on_timer(self) -> None:
        if time.monotonic() - self.last_publish >= self.period * 0.9:
            self._publish()

    def _on_get_settled(self, request: GetSettledObjects.Request,
                        response: GetSettledObjects.Response) -> GetSettledObjects.Response:
        """Wait (wall clock, up to timeout_s) for a settled frame stamped late enough."""
        if not (0.0 < request.timeout_s <= 600.0) or not request.max_speed >= 0.0:
            response.success = False
            response.message = (f"timeout_s must be in (0, 600] and max_speed >= 0; got "
                                f"{request.timeout_s}, {request.max_speed}")
            return response
        not_before = Time.from_msg(request.not_before).nanoseconds * 1e-9
        if not_before == 0.0:
            # Strictly after the request: a frame stamped now may have been taken before it.
            not_before = self.get_clock().now().nanoseconds * 1e-9 + 1e-9
        waiter = _SettleRequest(not_before, request.max_speed or None, threading.Event())
        with self.lock:
            if not request.max_speed and self.latest_settled is not None \
                    and self.latest_settled[0] >= not_before:
                response.success = True
                response.objects = self._objects_message(self.latest_settled[1])
                response.message = f"settled: {len(self.latest_settled[1])} objects"
                return response
            self.settle_requests.append(waiter)
        waiter.done.wait(request.timeout_s)
        with self.lock:
            self.settle_requests.remove(waiter)
            if waiter.result is None:
                reasons = self.tracker.unsettled_reasons() or ["objects still moving or no frames"]
                response.success = False
                response.message = (f"no settled observation within {request.timeout_s} s: "
                                    + ", ".join(reasons))
                response.objects = self._objects_message(self._estimates())
                return response
        response.success = True
        response.message = f"settled: {len(waiter.result)} objects"
        response.objects = self._objects_message(waiter.result)
        return response

    # ------------------------------------------------------------------------------ output
    def _estimates(self) -> list[ObjectEstimate]:
        """Current estimates, aged by the wall time since the last frame (call under lock)."""
        age = None if self.last_frame_arrival is None else \
            time.monotonic() - self.last_frame_arrival
        return self.tracker.estimates(age)

    def _objects_message(self, estimates: list[ObjectEstimate]) -> ObjectStateArray:
        msg = ObjectStateArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = FRAME_ID
        for estimate in estimates:
            state = ObjectState(
                id=estimate.id, object_class=estimate.object_class, shape=estimate.shape,
                x=estimate.pose.x, y=estimate.pose.y, theta=estimate.pose.theta,
                length=estimate.length, width=estimate.width, height=estimate.height,
                symmetry=estimate.symmetry, confidence=float(estimate.confidence),
                status=int(estimate.status))
            if estimate.last_seen is not None:
                state.last_seen = Time(nanoseconds=round(estimate.last_seen * 1e9)).to_msg()
            msg.objects.append(state)
        return msg

    def _publish(self) -> None:
        with self.lock:
            estimates = self._estimates()
        self.last_publish = time.monotonic()
        objects = self._objects_message(estimates)
        self.objects_pub.publish(objects)
        self.markers_pub.publish(self._markers(estimates, objects.header.stamp))

    def _markers(self, estimates: list[ObjectEstimate], stamp: TimeMsg) -> MarkerArray:
        markers = MarkerArray(markers=[Marker(action=Marker.DELETEALL)])
        for index, estimate in enumerate(estimates):
            r, g, b = STATUS_COLORS[estimate.status]
            z = self.table_height + estimate.height + 0.002
            outline = footprint_polygon(estimate.shape, estimate.length, estimate.width,
                                        estimate.pose)
            footprint = Marker(type=Marker.LINE_STRIP, ns="footprints", id=index,
                               action=Marker.ADD, color=ColorRGBA(r=r, g=g, b=b, a=1.0))
            footprint.header.frame_id, footprint.header.stamp = FRAME_ID, stamp
            footprint.scale.x = 0.003
            footprint.pose.orientation.w = 1.0
            footprint.points = [Point(x=float(px), y=float(py), z=z)
                                for px, py in [*outline, outline[0]]]
            label = Marker(type=Marker.TEXT_VIEW_FACING, ns="labels", id=index,
                           action=Marker.ADD, color=ColorRGBA(r=r, g=g, b=b, a=1.0),
                           text=f"{estimate.id} ({estimate.status.name.lower()})")
            label.header.frame_id, label.header.stamp = FRAME_ID, stamp
            label.scale.z = 0.02
            label.pose.position = Point(x=estimate.pose.x, y=estimate.pose.y, z=z + 0.03)
            label.pose.orientation.w = 1.0
            markers.markers += [footprint, label]
        return markers


# glibc's mallopt(M_MMAP_THRESHOLD): allocations from this size on are mmapped, and unmapped
# when freed.
M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES = -3, 128 * 1024


def pin_mmap_threshold() -> None:
    """Keep camera frames (0.9-1.2 MB each, 20 a second) out of the heap's arenas.

    glibc raises its mmap threshold to the size of each mmapped block freed, so after the first
    frames every frame buffer came from the per-thread arenas, which fragment: the node's RSS
    grew about 0.35 MB/s with frames flowing, 12.6 % over the soak test's 18 tasks. A fixed
    threshold turns this off. No-op where the C library is not glibc.
    """
    try:
        ctypes.CDLL("libc.so.6").mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
    except (OSError, AttributeError):
        pass


def main(args: list[str] | None = None) -> None:
    pin_mmap_threshold()
    run_node(PerceptionNode, "perception_node", threads=3, args=args)


if __name__ == "__main__":
    main()
