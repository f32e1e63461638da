"""A camera of a ROS bag from its ``sensor_msgs/CameraInfo``: the pinhole K (3, 3) and, when the
distortion coefficients ``D`` are not all zero, the undistortion of its images onto K
(``cv2.initUndistortRectifyMap`` for ``plumb_bob`` / ``rational_polynomial``, whose
coefficients are in OpenCV's order; ``cv2.fisheye`` for ``equidistant``): colour bilinear,
depth and labels nearest (no blending across depth edges or label ids). Pixels whose source
falls outside the image become 0 (invalid depth, black colour; labels: void).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from calnav.mapping import frame_geometry as fg
from calnav.mapping.sequences.readers import SEMANTIC_OFFSET

PINHOLE_MODELS = ("plumb_bob", "rational_polynomial")
FISHEYE_MODEL = "equidistant"


@dataclass
class Camera:
    """K (3, 3) float64 pixels, size (W, H) pixels, and undistortion maps (None: no distortion)."""

    k: np.ndarray
    size: tuple[int, int]
    map_x: np.ndarray | None = None
    map_y: np.ndarray | None = None

    def undistort(self, image: np.ndarray, nearest: bool) -> np.ndarray:
        """``image`` resampled onto the pinhole K (as it is without distortion). Integer label
        ids (int64, -1 = void) are resampled as uint16 class id + 1 (0 = void outside)."""
        if self.map_x is None:
            return image
        mode = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
        if image.dtype == np.int64:   # labels: remap has no int64; void (-1) -> 0 and back
            shifted = (image + SEMANTIC_OFFSET).astype(np.uint16)
            return cv2.remap(shifted, self.map_x, self.map_y, mode, borderMode=cv2.BORDER_CONSTANT).astype(
                np.int64) - SEMANTIC_OFFSET
        return cv2.remap(image, self.map_x, self.map_y, mode, borderMode=cv2.BORDER_CONSTANT)


def _field(msg, name: str):
    """A CameraInfo field by its ROS 2 name (``k``, ``d``); ROS 1 spells them ``K``, ``D``."""
    return getattr(msg, name) if hasattr(msg, name) else getattr(msg, name.upper())


def camera_from_info(msg, image_size: tuple[int, int]) -> Camera:
    """The ``Camera`` of a CameraInfo message whose images are ``image_size`` (W, H); ValueError
    for a size mismatch, an implausible K or an unknown distortion model."""
    w, h = int(msg.width), int(msg.height)
    if (w, h) != tuple(image_size):
        raise ValueError(f"it is for {w}x{h} images, the images are {image_size[0]}x{image_size[1]}")
    k = fg.check_intrinsics(np.asarray(_field(msg, "k"), np.float64).reshape(3, 3), w, h)
    d = np.asarray(_field(msg, "d"), np.float64)
    if not np.isfinite(d).all():
        raise ValueError(f"distortion coefficients D hold NaN or inf: {d.tolist()}")
    if not d.any():
        return Camera(k, (w, h))
    model = msg.distortion_model
    if model in PINHOLE_MODELS:
        map_x, map_y = cv2.initUndistortRectifyMap(k, d, None, k, (w, h), cv2.CV_32FC1)
    elif model == FISHEYE_MODEL and d.size == 4:
        map_x, map_y = cv2.fisheye.initUndistortRectifyMap(k, d, np.eye(3), k, (w, h), cv2.CV_32FC1)
    else:
        raise ValueError(f"distortion model {model!r} with D = {d.tolist()} is not supported; supported: "
                         f"{', '.join(PINHOLE_MODELS)}, {FISHEYE_MODEL} (4 coefficients), or D all zero")
    return Camera(k, (w, h), map_x, map_y)
