"""A camera_info file and a fake capture for camera-node tests."""

import numpy as np


def ros_yaml() -> str:
    return (
        "image_width: 32\nimage_height: 24\ncamera_name: test\n"
        "camera_matrix: {rows: 3, cols: 3, data: [30.0, 0.0, 16.0, 0.0, 30.0, 12.0, 0.0, 0.0, 1.0]}\n"
        "distortion_model: plumb_bob\ndistortion_coefficients: {rows: 1, cols: 5, data: [0.0, 0.0, 0.0, 0.0, 0.0]}\n"
    )


class FakeCapture:
    def read(self):
        return True, np.full((24, 32, 3), 50, np.uint8)

    def release(self):
        pass
