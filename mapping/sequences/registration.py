"""Colour camera -> depth camera resampling of rgb, label and logit images through the two
intrinsics (see ``mapping.sequences``)."""
from __future__ import annotations

import cv2
import numpy as np

from calnav.mapping.sequences.readers import VOID


class Registration:
    """Colour camera -> depth camera resampling (see the module docstring). Identity (no copy)
    when both cameras have the same K and size."""

    def __init__(self, k_color: np.ndarray, color_size: tuple[int, int], k_depth: np.ndarray,
                 depth_size: tuple[int, int]):
        self.color_size, self.depth_size = tuple(color_size), tuple(depth_size)
        self.identity = self.color_size == self.depth_size and np.allclose(k_color, k_depth, rtol=0, atol=1e-9)
        if self.identity:
            return
        wd, hd = depth_size
        wc, hc = color_size
        v, u = np.mgrid[0:hd, 0:wd].astype(np.float64)
        h = k_color @ np.linalg.inv(k_depth)
        z = h[2, 0] * u + h[2, 1] * v + h[2, 2]
        self.map_x = ((h[0, 0] * u + h[0, 1] * v + h[0, 2]) / z).astype(np.float32)
        self.map_y = ((h[1, 0] * u + h[1, 1] * v + h[1, 2]) / z).astype(np.float32)
        ui, vi = np.rint(self.map_x).astype(np.int64), np.rint(self.map_y).astype(np.int64)
        self.inside = ((ui >= 0) & (ui < wc) & (vi >= 0) & (vi < hc)).ravel()
        self.nearest = np.where(self.inside, vi.ravel() * wc + ui.ravel(), 0)

    def rgb(self, rgb: np.ndarray) -> np.ndarray:
        """(Hc, Wc, 3) uint8 -> (Hd, Wd, 3) uint8, bilinear (black outside the colour image)."""
        if self.identity:
            return rgb
        return cv2.remap(rgb, self.map_x, self.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

    def labels(self, labels: np.ndarray) -> np.ndarray:
        """(Hc, Wc) int class ids -> (Hd, Wd), nearest (void outside); labels already at the
        depth size are returned as they are."""
        if self.identity or (labels.shape[1], labels.shape[0]) == self.depth_size:
            return labels
        if (labels.shape[1], labels.shape[0]) != self.color_size:
            raise ValueError(f"label image is {labels.shape[1]}x{labels.shape[0]}; expected the colour size "
                             f"{self.color_size[0]}x{self.color_size[1]} or the depth size {self.depth_size[0]}x{self.depth_size[1]}")
        out = np.where(self.inside, labels.ravel()[self.nearest], VOID)
        return out.reshape(self.depth_size[1], self.depth_size[0])

    def logits(self, logits: np.ndarray) -> np.ndarray:
        """(Hc, Wc, K) -> (Hd, Wd, K) float32, nearest (all-zero = uniform outside)."""
        if self.identity:
            return logits
        k = logits.shape[2]
        out = np.take(logits.reshape(-1, k), self.nearest, axis=0).astype(np.float32, copy=False)
        out[~self.inside] = 0.0
        return out.reshape(self.depth_size[1], self.depth_size[0], k)
