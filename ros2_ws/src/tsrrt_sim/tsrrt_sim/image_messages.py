"""sensor_msgs/Image <-> numpy without cv_bridge (which is not on PyPI)."""

from __future__ import annotations

import array

import numpy as np
from sensor_msgs.msg import Image

# encoding -> (dtype, channels)
_ENCODINGS = {"rgb8": (np.uint8, 3), "bgr8": (np.uint8, 3), "mono8": (np.uint8, 1),
              "32FC1": (np.float32, 1), "16UC1": (np.uint16, 1)}


def numpy_to_image(pixels: np.ndarray, encoding: str) -> Image:
    """Image message (header left empty) from (H, W, C) or (H, W) pixels in `encoding`."""
    if encoding not in _ENCODINGS:
        raise ValueError(f"unsupported encoding {encoding!r}; supported: {sorted(_ENCODINGS)}")
    dtype, channels = _ENCODINGS[encoding]
    pixels = np.ascontiguousarray(pixels, dtype=dtype)
    expected_ndim = 2 if channels == 1 else 3
    if pixels.ndim != expected_ndim or (channels > 1 and pixels.shape[2] != channels):
        raise ValueError(f"{encoding} needs shape (H, W{'' if channels == 1 else ', 3'}), "
                         f"got {pixels.shape}")
    message = Image()
    message.height, message.width = pixels.shape[:2]
    message.encoding = encoding
    message.is_bigendian = 0
    message.step = pixels.shape[1] * channels * pixels.itemsize
    # Assigning an array.array skips the per-element checks of the generated setter.
    message.data = array.array("B", pixels.tobytes())
    return message


def image_to_numpy(message: Image) -> np.ndarray:
    """(H, W, C) or (H, W) pixels of an Image message (a copy)."""
    if message.encoding not in _ENCODINGS:
        raise ValueError(f"unsupported encoding {message.encoding!r}; "
                         f"supported: {sorted(_ENCODINGS)}")
    dtype, channels = _ENCODINGS[message.encoding]
    dtype = np.dtype(dtype).newbyteorder(">" if message.is_bigendian else "<")
    row_items = message.step // dtype.itemsize
    flat = np.frombuffer(bytes(message.data), dtype=dtype)
    rows = flat.reshape(message.height, row_items)[:, :message.width * channels]
    shape = (message.height, message.width) if channels == 1 else (
        message.height, message.width, channels)
    return rows.reshape(shape).astype(dtype.newbyteorder("="))
