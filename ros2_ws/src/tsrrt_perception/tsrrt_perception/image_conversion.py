"""sensor_msgs/Image fields <-> numpy, because cv_bridge is not on PyPI.

ROS-free: functions take the message's fields, not the message, so they are testable without rclpy;
the node passes `msg.encoding, msg.width, ...` straight through. Rows may be padded (`step` larger
than width * bytes per pixel) and multi-byte pixels may be big-endian; both are honoured.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tsrrt_common.errors import TsrrtError


class ImageConversionError(TsrrtError):
    """An image cannot be converted; the message says why (encoding, size, step, data length)."""


@dataclass(frozen=True)
class EncodingLayout:
    """How one ROS image encoding stores a pixel."""

    dtype: np.dtype
    channels: int


ENCODINGS: dict[str, EncodingLayout] = {
    "rgb8": EncodingLayout(np.dtype(np.uint8), 3),
    "bgr8": EncodingLayout(np.dtype(np.uint8), 3),
    "mono8": EncodingLayout(np.dtype(np.uint8), 1),
    "32FC1": EncodingLayout(np.dtype(np.float32), 1),
    "16UC1": EncodingLayout(np.dtype(np.uint16), 1),
}


@dataclass(frozen=True)
class ImageFields:
    """The fields of a sensor_msgs/Image that describe its pixels."""

    encoding: str
    width: int
    height: int
    step: int
    is_bigendian: bool
    data: bytes


def _layout(encoding: str) -> EncodingLayout:
    try:
        return ENCODINGS[encoding]
    except KeyError:
        raise ImageConversionError(
            f"unsupported encoding {encoding!r}; supported: {sorted(ENCODINGS)}") from None


def image_to_array(encoding: str, width: int, height: int, step: int, is_bigendian: bool,
                   data: bytes | bytearray | memoryview) -> np.ndarray:
    """Pixels of an image message as a native-endian array.

    Returns:
        (height, width) for one-channel encodings, (height, width, 3) for rgb8/bgr8 (channel
        order as encoded). The array is a copy that owns its memory.

    Raises:
        ImageConversionError: unknown encoding, empty image, step too small, or data of the
            wrong length.
    """
    layout = _layout(encoding)
    if width <= 0 or height <= 0:
        raise ImageConversionError(f"empty image ({width}x{height}, encoding {encoding})")
    row_bytes = width * layout.channels * layout.dtype.itemsize
    if step < row_bytes:
        raise ImageConversionError(
            f"step {step} is smaller than width {width} x {layout.channels} channel(s) x "
            f"{layout.dtype.itemsize} byte(s) = {row_bytes} for {encoding}")
    buffer = np.frombuffer(data, dtype=np.uint8)
    if buffer.size != step * height:
        raise ImageConversionError(
            f"data has {buffer.size} bytes, expected step {step} x height {height} = "
            f"{step * height} for a {width}x{height} {encoding} image")
    rows = buffer.reshape(height, step)[:, :row_bytes]
    dtype = layout.dtype.newbyteorder(">" if is_bigendian else "<")
    pixels = np.ascontiguousarray(rows).view(dtype).astype(layout.dtype.newbyteorder("="))
    shape = (height, width) if layout.channels == 1 else (height, width, layout.channels)
    return pixels.reshape(shape)


def array_to_image(array: np.ndarray, encoding: str) -> ImageFields:
    """Image message fields for an array (unpadded rows, little-endian).

    Args:
        array: (height, width) for one-channel encodings or (height, width, 3) for rgb8/bgr8.
        encoding: one of ENCODINGS.
    """
    layout = _layout(encoding)
    expected_ndim = 2 if layout.channels == 1 else 3
    if array.ndim != expected_ndim or (layout.channels > 1 and array.shape[2] != layout.channels):
        raise ImageConversionError(
            f"array of shape {array.shape} does not fit {encoding} "
            f"({layout.channels} channel(s))")
    if array.size == 0:
        raise ImageConversionError(f"empty array of shape {array.shape}")
    little = np.ascontiguousarray(array, dtype=layout.dtype.newbyteorder("<"))
    height, width = array.shape[:2]
    return ImageFields(encoding, width, height, width * layout.channels * layout.dtype.itemsize,
                       False, little.tobytes())
