"""Bad camera messages published to a running perception_node: skipped with a logged reason.

The test's probe plays the camera (colour, depth and CameraInfo on the simulator's topics, with
the simulator's QoS) for a perception_node started alone. Each bad message must leave a warning
naming the problem in the node's log (each distinct reason is logged at once), and the node must
keep running; at the end a good frame is still turned into a tracked object.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

pytestmark = pytest.mark.integration

rclpy = pytest.importorskip("rclpy")
from builtin_interfaces.msg import Time as TimeMessage  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image  # noqa: E402

from tsrrt_common.camera import OverheadCamera  # noqa: E402
from tsrrt_common.geometry import Pose2D  # noqa: E402
from tsrrt_common.object_classes import load_class_table  # noqa: E402
from tsrrt_interfaces.msg import ObjectState, ObjectStateArray  # noqa: E402
from tsrrt_perception.scene_rendering import TabletopRenderer  # noqa: E402

CATEGORY = "messages"
CAMERA = OverheadCamera()
# Bad frames are small: every check they trip comes before the size is compared with the
# camera's, and big best-effort messages on a loaded machine are often dropped in pieces.
W, H = 8, 6
ERASER_POSE = Pose2D(0.45, 0.02, 0.4)
BYTES_PER_PIXEL = {"rgb8": 3, "bgr8": 3, "yuv422": 2, "32FC1": 4, "16UC1": 2}


def image(encoding: str, width: int = W, height: int = H, step: int | None = None,
          data: bytes | None = None) -> Image:
    """An Image with the given layout and (unless given) zero pixels of the right length."""
    step = width * BYTES_PER_PIXEL[encoding] if step is None else step
    return Image(encoding=encoding, width=width, height=height, step=step,
                 data=bytes(step * height) if data is None else data)


def camera_info(k: list[float] | None = None, width: int = CAMERA.width,
                height: int = CAMERA.height) -> CameraInfo:
    info = CameraInfo(width=width, height=height, distortion_model="plumb_bob")
    info.k = CAMERA.intrinsics.ravel().tolist() if k is None else k
    return info


class Camera:
    """The probe's publishers on the camera topics, stamping each frame one second later."""

    def __init__(self, probe) -> None:
        self.probe = probe
        images = QoSProfile(depth=2, reliability=ReliabilityPolicy.RELIABLE)   # as perception asks
        self.colour = probe.create_publisher(Image, "/camera/image_raw", images)
        self.depth = probe.create_publisher(Image, "/camera/depth/image_raw", images)
        self.info = probe.create_publisher(CameraInfo, "/camera/camera_info",
                                           qos_profile_sensor_data)
        self.seconds = 0
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.objects = probe.record(ObjectStateArray, "/perception/objects", reliable)

    def connected(self) -> bool:
        return all(p.get_subscription_count() > 0 for p in (self.colour, self.depth, self.info))

    def publish(self, colour: Image, depth: Image, info: CameraInfo | None) -> None:
        self.seconds += 1
        stamp = TimeMessage(sec=self.seconds)
        for message in (info, colour, depth):
            if message is not None:
                message.header.stamp = stamp
                message.header.frame_id = "camera_optical"
                (self.info if message is info else self.colour if message is colour
                 else self.depth).publish(message)

    def until_logged(self, process, fragment: str, colour: Image, depth: Image,
                     info: CameraInfo | None, timeout: float = 60.0) -> bool:
        """Publish the frame every 0.3 s (best effort may drop one) until the log shows it."""
        assert self.probe.spin_until(self.connected, 30.0), "perception does not subscribe"
        start = len(process.log())
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.publish(colour, depth, info)
            if process.wait_for_log(fragment, timeout=0.3, after=start):
                return True
        return False


@pytest.fixture(scope="module")
def perception(launch):
    return launch.start("tsrrt_perception", "perception_node")


@pytest.fixture(scope="module")
def camera(perception, graph_probe) -> Camera:
    return Camera(graph_probe)


def good_frame() -> tuple[Image, Image]:
    """A rendered eraser on the table, as the simulator would publish it."""
    renderer = TabletopRenderer(CAMERA, pixel_centre_fix=True)
    try:
        renderer.add("eraser", load_class_table()["eraser"], (0.8, 0.2, 0.2))
        renderer.place("eraser", ERASER_POSE)
        frame = renderer.render()
    finally:
        renderer.close()
    colour = image("rgb8", CAMERA.width, CAMERA.height, data=frame.rgb.tobytes())
    depth = image("32FC1", CAMERA.width, CAMERA.height,
                  data=frame.depth.astype("<f4").tobytes())
    return colour, depth


@pytest.mark.parametrize("what, code, fragment", [pytest.param(
    "frames before any CameraInfo", "frame skipped, warning logged",
    "skipping frame: no CameraInfo received yet", id="frames before any CameraInfo")])
def test_frames_without_camera_info_are_skipped(launch, probe_on_domain, what, code, fragment):
    # A node of its own: the module's node has had CameraInfo by the time this could run.
    env = launch.other_domain_env()
    process = launch.start("tsrrt_perception", "perception_node", env=env)
    lonely = Camera(probe_on_domain(int(env["ROS_DOMAIN_ID"])))
    assert lonely.until_logged(process, fragment, image("rgb8"), image("32FC1"), None), \
        process.log()
    assert process.running


MESSAGE_CASES = [
    ("CameraInfo with K all zero", image("rgb8"), image("32FC1"), camera_info(k=[0.0] * 9),
     "unusable CameraInfo: CameraInfo K is all zero: the camera is uncalibrated"),
    ("CameraInfo of size 0x0", image("rgb8"), image("32FC1"), camera_info(width=0, height=0),
     "unusable CameraInfo: CameraInfo image size 0x0 is empty"),
    ("CameraInfo K that is not a pinhole matrix", image("rgb8"), image("32FC1"),
     camera_info(k=[500.0, 0, 320, 0, 500.0, 240, 0, 0, 0]), "is not a valid pinhole matrix"),
    ("colour in an unsupported encoding (yuv422)", image("yuv422"), image("32FC1"),
     camera_info(), "skipping frame: unsupported encoding 'yuv422'; supported: ["),
    ("colour image in a depth encoding", image("32FC1"), image("32FC1"), camera_info(),
     "skipping frame: colour image has encoding '32FC1', expected rgb8 or bgr8"),
    ("depth image in a colour encoding", image("rgb8"), image("rgb8"), camera_info(),
     "skipping frame: depth image has encoding 'rgb8', expected 32FC1/16UC1"),
    ("data shorter than step x height", image("rgb8", data=bytes(100)), image("32FC1"),
     camera_info(), f"skipping frame: data has 100 bytes, expected step {3 * W} x height {H}"),
    ("step smaller than a row", image("rgb8"), image("32FC1", step=10), camera_info(),
     f"skipping frame: step 10 is smaller than width {W} x 1 channel(s) x 4 byte(s)"),
    ("empty 0x0 image", image("rgb8", 0, 0), image("32FC1"), camera_info(),
     "skipping frame: empty image (0x0, encoding rgb8)"),
    ("colour and depth of different sizes", image("rgb8"), image("32FC1", W // 2, H // 2),
     camera_info(), f"skipping frame: colour {W}x{H} and depth {W // 2}x{H // 2} differ in size"),
    ("images of another size than CameraInfo", image("rgb8"), image("32FC1"), camera_info(),
     f"skipping frame: depth image is {W}x{H} but CameraInfo says "
     f"{CAMERA.width}x{CAMERA.height}"),
]


@pytest.mark.parametrize("what, colour, depth, info, code, fragment", [
    pytest.param(what, colour, depth, info, "frame skipped, warning logged", fragment, id=what)
    for what, colour, depth, info, fragment in MESSAGE_CASES])
def test_bad_camera_message_is_skipped_with_the_reason(perception, camera, what, colour, depth,
                                                       info, code, fragment):
    assert camera.until_logged(perception, fragment, colour, depth, info), perception.log()
    assert perception.running, perception.log()


def test_a_good_frame_is_still_processed_after_the_bad_ones(perception, camera):
    colour, depth = good_frame()

    def eraser_tracked() -> bool:
        return bool(camera.objects) and any(
            o.object_class == "eraser" and o.status == ObjectState.STATUS_TRACKED
            and math.hypot(o.x - ERASER_POSE.x, o.y - ERASER_POSE.y) < 0.01
            for o in camera.objects[-1].objects)

    for _ in range(200):      # a minute: a full-size frame may need a few tries under load
        camera.publish(colour, depth, camera_info())
        if camera.probe.spin_until(eraser_tracked, 0.3):
            break
    assert eraser_tracked(), perception.log()
    log = perception.log()
    assert perception.running and "Traceback" not in log, log
    assert np.isfinite([o.x for o in camera.objects[-1].objects]).all()
