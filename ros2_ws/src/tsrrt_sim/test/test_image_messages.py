"""Image message conversion without cv_bridge."""

import numpy as np
import pytest

from tsrrt_sim.image_messages import image_to_numpy, numpy_to_image


@pytest.mark.parametrize("encoding, pixels", [
    ("rgb8", np.random.default_rng(1).integers(0, 256, (4, 5, 3), dtype=np.uint8)),
    ("32FC1", np.random.default_rng(2).uniform(0.1, 2.0, (4, 5)).astype(np.float32)),
])
def test_round_trip_keeps_pixels(encoding, pixels):
    message = numpy_to_image(pixels, encoding)
    assert (message.height, message.width) == pixels.shape[:2]
    assert message.step == pixels.shape[1] * pixels.itemsize * (3 if pixels.ndim == 3 else 1)
    np.testing.assert_array_equal(image_to_numpy(message), pixels)


def test_wrong_shape_or_encoding_is_refused():
    with pytest.raises(ValueError, match="rgb8 needs shape"):
        numpy_to_image(np.zeros((4, 5), np.uint8), "rgb8")
    with pytest.raises(ValueError, match="unsupported encoding 'yuv422'"):
        numpy_to_image(np.zeros((4, 5), np.uint8), "yuv422")
