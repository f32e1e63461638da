"""The simulator's semantic class list: Habitat's six ObjectNav goal categories first (ids 0-5,
so a goal category id is also its class id), then distractor furniture, then structure.

Every array of class ids in calnav uses these ids; ``VOID`` (-1 in int arrays, 255 in uint8
images) marks pixels / triangles / voxels with no label (sky, unlabelled scan faces).
"""
from __future__ import annotations

import numpy as np

GOAL_CATEGORIES: tuple[str, ...] = ("chair", "bed", "plant", "toilet", "tv_monitor", "sofa")
DISTRACTOR_CLASSES: tuple[str, ...] = (
    "table", "cabinet", "shelf", "counter", "sink", "bathtub", "stool", "desk",
)
STRUCTURE_CLASSES: tuple[str, ...] = ("floor", "wall", "ceiling", "door")

CLASS_NAMES: tuple[str, ...] = GOAL_CATEGORIES + DISTRACTOR_CLASSES + STRUCTURE_CLASSES
NUM_CLASSES: int = len(CLASS_NAMES)
CLASS_ID: dict[str, int] = {name: i for i, name in enumerate(CLASS_NAMES)}

VOID: int = -1
VOID_U8: int = 255

STRUCTURE_IDS: tuple[int, ...] = tuple(CLASS_ID[n] for n in STRUCTURE_CLASSES)
GOAL_IDS: tuple[int, ...] = tuple(range(len(GOAL_CATEGORIES)))

# A fixed, distinguishable colour per class for visualisation (not the rendered albedo).
PALETTE: np.ndarray = np.array(
    [
        [230, 25, 75], [60, 180, 75], [20, 160, 20], [0, 130, 200], [145, 30, 180], [245, 130, 48],
        [170, 110, 40], [128, 128, 0], [210, 180, 140], [0, 128, 128], [70, 240, 240],
        [250, 190, 212], [255, 225, 25], [128, 0, 0], [200, 200, 200], [120, 120, 120],
        [60, 60, 60], [170, 255, 195],
    ],
    dtype=np.uint8,
)
assert len(PALETTE) == NUM_CLASSES


def class_id(name: str) -> int:
    """Class id of ``name``; a clear error lists the valid names."""
    try:
        return CLASS_ID[name]
    except KeyError:
        raise ValueError(f"unknown class {name!r}; valid classes: {', '.join(CLASS_NAMES)}") from None


def colorize(labels: np.ndarray) -> np.ndarray:
    """(H, W) int class ids (VOID / 255 allowed) -> (H, W, 3) uint8 colours, void black."""
    labels = np.asarray(labels).astype(np.int64)
    out = np.zeros(labels.shape + (3,), dtype=np.uint8)
    valid = (labels >= 0) & (labels < NUM_CLASSES)
    out[valid] = PALETTE[labels[valid]]
    return out
