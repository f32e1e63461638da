"""The agent-env contract of the ObjectNav task, in one file: actions, observation keys and
shapes, and the conventions an agent needs to turn Habitat's sensors into geometry.

Actions follow habitat-lab's ObjectNav action space order (STOP=0, MOVE_FORWARD=1,
TURN_LEFT=2, TURN_RIGHT=3, LOOK_UP=4, LOOK_DOWN=5); LOOK_UP/DOWN exist only when the
environment is configured with ``enable_look: true``.

Observations (``observation_specs``): an agent may read only ``HABITAT_KEYS`` -- what
habitat-lab's ObjectNav task gives -- plus ``SEMANTIC`` for ground-truth-based segmenters
(like a Habitat semantic sensor):

- ``rgb`` (H, W, 3) uint8;
- ``depth`` (H, W, 1) float32: metres (0 = invalid) or, with ``normalize_depth``, Habitat's
  normalised depth (d - min) / (max - min) in [0, 1] (0 = invalid); ``depth_to_metres`` undoes it;
- ``gps`` (2,) float32 (forward, right) metres from the start position in the start pose's frame
  (habitat-lab's EpisodicGPSSensor, dimensionality 2);
- ``compass`` (1,) float32 radians, heading relative to the start heading, counter-clockwise
  positive, in [-pi, pi] (habitat-lab's EpisodicCompassSensor, an atan2);
- ``objectgoal`` (1,) int64 goal category id.

``camera_pose`` / ``camera_intrinsics`` (``DEBUG_KEYS``: privileged world-frame pose, Habitat
gives none) are emitted for debugging and for the simulated ``noisy`` segmenter; no decision of
an agent may depend on them. The agent package splits them off at its boundary
(``agent.contract``) and hands them only to the parts that declare them. An oracle's access to
the simulator itself is the other privileged input: ``SimulatorHandle`` (below), which an env
provides (``ObjectNavEnv.simulator_handle``) and only an agent declaring it is given.

The start frame: origin at the start position on the floor, +x forward at the start, +y to
the left, +z up (metres). ``gps_compass_to_xy_yaw`` maps (gps, compass) into it; the camera is
then at height ``camera_height_m`` with intrinsics ``pinhole_intrinsics(W, H, hfov_deg)`` (task
facts from the config, as in Habitat), so ``camera_pose`` gives the start-frame camera pose.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from typing import Mapping, Protocol

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
        # a bool is an int to Python, but True is no action id (it would be MOVE_FORWARD)
        a = None if isinstance(action, (bool, np.bool_)) else int(action)
    except (TypeError, ValueError):
        a = None
    n = num_actions(enable_look)
    if a is None or not 0 <= a < n or a != action:
        valid = ", ".join(f"{i}={Action(i).name}" for i in range(n))
        raise ValueError(f"invalid action {action!r}; valid actions: {valid}")
    return Action(a)



# ----------------------------------------------------------------------- observation keys
RGB, DEPTH, GPS, COMPASS, OBJECTGOAL = "rgb", "depth", "gps", "compass", "objectgoal"
SEMANTIC = "semantic"
CAMERA_POSE, CAMERA_INTRINSICS = "camera_pose", "camera_intrinsics"
HABITAT_KEYS: tuple[str, ...] = (RGB, DEPTH, GPS, COMPASS, OBJECTGOAL)  # what habitat-lab's ObjectNav gives
DEBUG_KEYS: tuple[str, ...] = (CAMERA_POSE, CAMERA_INTRINSICS)          # privileged: never for decisions
UNBOUNDED = math.inf


@dataclass(frozen=True)
class ObsSpec:
    """One observation: shape, dtype and bounds (inclusive) of its values."""

    shape: tuple[int, ...]
    dtype: type
    low: float
    high: float


def observation_specs(width: int, height: int, num_goals: int, num_classes: int, max_depth_m: float,
                      normalize_depth: bool, semantic: bool) -> dict[str, ObsSpec]:
    """The observation dict's keys -> ``ObsSpec`` (the env builds its gym spaces from this).
    width x height pixels; num_goals goal categories; num_classes semantic classes (ids 0..K-1,
    -1 void); depth bounded by max_depth_m metres, or by 1 when normalised; ``semantic`` adds
    the ground-truth semantic image."""
    specs = {
        RGB: ObsSpec((height, width, 3), np.uint8, 0, 255),
        DEPTH: ObsSpec((height, width, 1), np.float32, 0.0, 1.0 if normalize_depth else max_depth_m),
        GPS: ObsSpec((2,), np.float32, -UNBOUNDED, UNBOUNDED),
        COMPASS: ObsSpec((1,), np.float32, -math.pi, math.pi),
        OBJECTGOAL: ObsSpec((1,), np.int64, 0, num_goals - 1),
        CAMERA_POSE: ObsSpec((4, 4), np.float64, -UNBOUNDED, UNBOUNDED),
        CAMERA_INTRINSICS: ObsSpec((3, 3), np.float64, 0.0, UNBOUNDED),
    }
    if semantic:
        specs[SEMANTIC] = ObsSpec((height, width), np.int16, -1, num_classes - 1)
    return specs


class SimulatorHandle(Protocol):
    """Privileged access to the simulator for an oracle agent (never for a real agent's
    decisions): the shortest-path follower on the simulator's navigation grid, from the agent's
    true pose to the current episode's goal. An env provides it (``ObjectNavEnv.simulator_handle``;
    ``calnav habitat-benchmark`` builds one on habitat-lab's ``CalnavSim-v0``)."""

    @property
    def max_episode_steps(self) -> int:
        """The env's step limit (actions per episode)."""

    def reset(self) -> None:
        """A new episode has begun (call after the env's reset): forget the previous plan."""

    def shortest_path_action(self) -> Action:
        """The follower's next action (STOP once within the success distance)."""


def require_keys(obs: Mapping, keys, needed_by: str = "an ObjectNav agent") -> None:
    """A clear one-line error naming the missing observation keys, who needs them and the keys
    present."""
    missing = [k for k in keys if k not in obs]
    if missing:
        raise KeyError(f"observation lacks {', '.join(missing)}, which {needed_by} needs "
                       f"({', '.join(keys)}); it has: {', '.join(sorted(obs))}")


# ----------------------------------------------------------------------- geometry conventions
def wrap_angle(a: float) -> float:
    """Angle (rad) wrapped to [-pi, pi)."""
    return (a + math.pi) % (2 * math.pi) - math.pi


# Quaternions (w, x, y, z) with numpy-quaternion's arithmetic, term for term (Hamilton product
# in its order, inverse = conjugate / squared norm): habitat-lab's GPS and compass sensors compute
# with it, and calnav repeats the very operations so that its gps / compass equal habitat-lab's
# bit for bit. A 1e-7 difference in a pose is enough to move a map cell and, later, an action.
Quat = tuple[float, float, float, float]


def _qmul(a: Quat, b: Quat) -> Quat:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


def _qinv(q: Quat) -> Quat:
    w, x, y, z = q
    n = w * w + x * x + y * y + z * z
    return (w / n, -x / n, -y / n, -z / n)


def _qrotate(q: Quat, v) -> tuple[float, float, float]:
    """habitat-lab's ``quaternion_rotate_vector``: the vector part of q * (0, v) * q^-1."""
    return _qmul(_qmul(q, (0.0, float(v[0]), float(v[1]), float(v[2]))), _qinv(q))[1:]


def yaw_to_habitat_quaternion(yaw: float) -> list[float]:
    """calnav yaw (rad, ccw from +x about +z) -> Habitat [x, y, z, w] rotation about +y (forward -z)."""
    theta = yaw - math.pi / 2
    return [0.0, math.sin(theta / 2), 0.0, math.cos(theta / 2)]


def xy_yaw_to_gps_compass(xy, yaw: float, start_xy, start_rotation) -> tuple[np.ndarray, np.ndarray]:
    """Habitat's EpisodicGPSSensor (2D) and EpisodicCompassSensor of an agent at world ``xy``
    (2,) metres heading ``yaw`` rad (ccw from world +x), for an episode that started at
    ``start_xy`` with Habitat start quaternion ``start_rotation`` [x, y, z, w] (as stored in the
    episode file). Returns gps (2,) float32 (forward, right) metres and compass (1,) float32 rad.

    Computed exactly as habitat-lab does (its start position in float32, numpy-quaternion's
    arithmetic, Habitat's y-up frame in which calnav (x, y) is (x, ., -y)), so the values are
    bit-identical to habitat-lab's on the same episode (``tests/agent/test_habitat_agent.py``)."""
    sx, sy, sz, sw = (float(c) for c in start_rotation)
    start = (sw, sx, sy, sz)
    origin = np.array([start_xy[0], 0.0, -start_xy[1]], np.float32)
    p = _qrotate(_qinv(start), np.array([xy[0], 0.0, -xy[1]], np.float64) - origin)
    x, y, z, w = yaw_to_habitat_quaternion(yaw)
    h = _qrotate(_qmul(_qinv((w, x, y, z)), start), (0.0, 0.0, -1.0))
    return np.array([-p[2], p[0]], np.float32), np.array([np.arctan2(h[0], -h[2])], np.float32)


def gps_compass_to_xy_yaw(gps, compass) -> tuple[np.ndarray, float]:
    """Start-frame position (2,) float64 metres (x forward at the start, y left) and heading
    (rad, ccw from the start heading) of gps (2,) (forward, right) and compass (1,)."""
    g = np.asarray(gps, np.float64).reshape(-1)
    return np.array([g[0], -g[1]]), float(np.asarray(compass, np.float64).reshape(-1)[0])


def camera_pose(xy, yaw: float, height: float, pitch: float = 0.0) -> np.ndarray:
    """(4, 4) float64 world-from-camera pose, OpenCV camera axes (x right, y down, z forward).

    xy: (2,) position, metres; yaw: heading counter-clockwise from +x about +z, radians;
    height: z of the camera centre, metres (the camera height above a floor at z = 0); pitch:
    radians, positive looks up. yaw = pitch = 0 gives forward (1, 0, 0), right (0, -1, 0),
    down (0, 0, -1).
    """
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    forward = np.array([cp * cy, cp * sy, sp])
    right = np.array([sy, -cy, 0.0])
    down = np.cross(forward, right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2] = right, down, forward
    pose[:3, 3] = (float(xy[0]), float(xy[1]), float(height))
    return pose


def pinhole_intrinsics(width: int, height: int, hfov_deg: float) -> np.ndarray:
    """(3, 3) float64 K of Habitat's pinhole sensor: square pixels, fx = fy = (W / 2) /
    tan(hfov / 2), principal point at the image centre in the OpenCV pixel-centre convention
    (pixel (u, v) centred at (u, v), so cx = (W - 1) / 2, cy = (H - 1) / 2)."""
    f = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
    return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def normalize_depth_m(depth_m: np.ndarray, min_depth_m: float, max_depth_m: float) -> np.ndarray:
    """Metres (0 = invalid) -> Habitat's normalised depth (d - min) / (max - min), float32 in
    [0, 1]; invalid pixels stay 0 (Habitat clips them to min_depth, which also reads 0)."""
    d = np.asarray(depth_m, np.float32)
    out = np.clip((d - np.float32(min_depth_m)) / np.float32(max_depth_m - min_depth_m), 0.0, 1.0)
    return np.where(d > 0, out, np.float32(0.0)).astype(np.float32)


def depth_to_metres(depth: np.ndarray, normalized: bool, min_depth_m: float, max_depth_m: float) -> np.ndarray:
    """An observation's depth in metres, float32 (0 = invalid). Normalised depth x maps to
    min + x (max - min); x = 0 (Habitat's reading for missing / too-near depth) and x = 1
    (too far) are invalid, as PEANUT treats them."""
    d = np.asarray(depth, np.float32)
    if not normalized:
        return d
    valid = (d > 0) & (d < 1)
    return np.where(valid, np.float32(min_depth_m) + d * np.float32(max_depth_m - min_depth_m),
                    np.float32(0.0)).astype(np.float32)
