"""Image message fields <-> numpy: layouts, padding, byte order, and clear errors."""

import numpy as np
import pytest

from tsrrt_perception.image_conversion import (
    ImageConversionError,
    array_to_image,
    image_to_array,
)

RNG = np.random.default_rng(3)


@pytest.mark.parametrize("encoding, array", [
    ("rgb8", RNG.integers(0, 256, (5, 7, 3), dtype=np.uint8)),
    ("bgr8", RNG.integers(0, 256, (5, 7, 3), dtype=np.uint8)),
    ("mono8", RNG.integers(0, 256, (5, 7), dtype=np.uint8)),
    ("32FC1", RNG.uniform(0.1, 2.0, (5, 7)).astype(np.float32)),
    ("16UC1", RNG.integers(0, 65536, (5, 7), dtype=np.uint16)),
])
def test_round_trip(encoding, array):
    fields = array_to_image(array, encoding)
    back = image_to_array(fields.encoding, fields.width, fields.height, fields.step,
                          fields.is_bigendian, fields.data)
    assert back.dtype == array.dtype and back.dtype.isnative
    np.testing.assert_array_equal(back, array)


def test_padded_rows_are_skipped():
    depth = RNG.uniform(0.5, 1.0, (4, 3)).astype(np.float32)
    step = 3 * 4 + 8                                     # 8 bytes of padding per row
    rows = np.full((4, step), 0xAB, np.uint8)
    rows[:, :12] = depth.view(np.uint8).reshape(4, 12)
    back = image_to_array("32FC1", 3, 4, step, False, rows.tobytes())
    np.testing.assert_array_equal(back, depth)


def test_padded_rgb_rows():
    rgb = RNG.integers(0, 256, (3, 5, 3), dtype=np.uint8)
    padded = np.zeros((3, 16), np.uint8)
    padded[:, :15] = rgb.reshape(3, 15)
    np.testing.assert_array_equal(image_to_array("rgb8", 5, 3, 16, False, padded.tobytes()), rgb)


@pytest.mark.parametrize("encoding, dtype", [("32FC1", np.float32), ("16UC1", np.uint16)])
def test_big_endian(encoding, dtype):
    values = np.arange(12, dtype=dtype).reshape(3, 4) * dtype(3) + dtype(1)
    data = values.astype(np.dtype(dtype).newbyteorder(">")).tobytes()
    back = image_to_array(encoding, 4, 3, 4 * values.itemsize, True, data)
    np.testing.assert_array_equal(back, values)
    assert back.dtype.isnative


def test_little_endian_data_read_as_big_endian_differs():
    values = np.array([[1.5, 2.5]], np.float32)
    back = image_to_array("32FC1", 2, 1, 8, True, values.tobytes())
    assert not np.array_equal(back, values)


@pytest.mark.parametrize("args, reason", [
    (("yuv422", 2, 2, 4, False, bytes(8)), "unsupported encoding 'yuv422'"),
    (("mono8", 0, 2, 0, False, b""), "empty image"),
    (("rgb8", 4, 2, 11, False, bytes(22)), "step 11 is smaller than"),
    (("32FC1", 4, 2, 16, False, bytes(31)), "data has 31 bytes, expected"),
    (("16UC1", 4, 2, 8, False, b""), "data has 0 bytes"),
])
def test_bad_images_name_the_problem(args, reason):
    with pytest.raises(ImageConversionError, match=reason):
        image_to_array(*args)


def test_array_of_wrong_shape_is_rejected():
    with pytest.raises(ImageConversionError, match="does not fit rgb8"):
        array_to_image(np.zeros((4, 4), np.uint8), "rgb8")
