"""The ObjectNav task's interface types: the action enum and the observation record.

Action ids follow habitat-lab's ObjectNav action space order (STOP=0, MOVE_FORWARD=1,
TURN_LEFT=2, TURN_RIGHT=3, LOOK_UP=4, LOOK_DOWN=5); LOOK_UP/DOWN exist only when the
environment is configured with ``enable_look: true``.
"""
from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np


class Action(IntEnum):
    STOP = 0
    MOVE_FORWARD = 1
    TURN_LEFT = 2
    TURN_RIGHT = 3
    LOOK_UP = 4
    LOOK_DOWN = 5


def num_actions(enable_look: bool) -> int:
    return 6 if enable_look else 4


def check_action(action, enable_look: bool) -> Action:
    """Validate an action id; a clear error lists the valid ids and names."""
    try:
        a = int(action)
    except (TypeError, ValueError):
        a = None
    n = num_actions(enable_look)
    if a is None or not 0 <= a < n or a != action:
        valid = ", ".join(f"{i}={Action(i).name}" for i in range(n))
        raise ValueError(f"invalid action {action!r}; valid actions: {valid}")
    return Action(a)


@dataclass
class Observations:
    """One step's sensor readings, as the agent sees them.

    rgb: (H, W, 3) uint8. depth: (H, W) float32 metres, 0 where invalid (no hit, out of range).
    semantic: (H, W) int16 ground-truth class ids (-1 void) or None when the sensor is off.
    gps: (2,) float32 metres, (forward, right) of the agent relative to its start pose.
    compass: float radians, heading relative to the start heading, counter-clockwise positive.
    goal: goal category id (0-5). camera_pose: (4, 4) float64 world-from-camera (OpenCV
    camera axes: x right, y down, z forward). intrinsics: (3, 3) float64 pinhole matrix.
    """

    rgb: np.ndarray
    depth: np.ndarray
    semantic: np.ndarray | None
    gps: np.ndarray
    compass: float
    goal: int
    camera_pose: np.ndarray
    intrinsics: np.ndarray
