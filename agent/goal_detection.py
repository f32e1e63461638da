"""Goal detection: threshold the goal class's confidence map and keep the largest connected
component if it is big enough (PEANUT / SemExp style)."""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

CONNECTIVITY = 8  # cells touching at corners belong to one component


@dataclass
class GoalDetection:
    """found: a component passed; mask (n, n) bool the chosen component (all False if not
    found); area in cells; peak the highest confidence in the component."""

    found: bool
    mask: np.ndarray
    area: int
    peak: float


def largest_component(mask: np.ndarray, min_area: int) -> tuple[np.ndarray, int]:
    """The largest 8-connected component of a bool mask (n, n) with at least ``min_area``
    cells, and its area (an all-False mask and 0 when none)."""
    out = np.zeros_like(mask, bool)
    if not mask.any():
        return out, 0
    rows, cols = np.nonzero(mask)
    r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1  # crop: cost ~ object size
    num, labels, stats, _ = cv2.connectedComponentsWithStats(mask[r0:r1, c0:c1].astype(np.uint8), connectivity=CONNECTIVITY)
    if num <= 1:
        return out, 0
    areas = stats[1:, cv2.CC_STAT_AREA]
    best = int(np.argmax(areas))
    if areas[best] < min_area:
        return out, 0
    out[r0:r1, c0:c1] = labels == best + 1
    return out, int(areas[best])


def detect_goal(confidence: np.ndarray, threshold: float, min_area: int, exclude: np.ndarray | None = None) -> GoalDetection:
    """confidence (n, n) float in [0, 1] of the goal class; cells >= ``threshold`` (and not in
    the optional bool ``exclude`` mask) are candidates; found when the largest component has
    >= ``min_area`` cells."""
    cand = confidence >= threshold
    if exclude is not None:
        cand &= ~exclude
    mask, area = largest_component(cand, min_area)
    peak = float(confidence[mask].max()) if area else 0.0
    return GoalDetection(area > 0, mask, area, peak)
