"""Hand-held scanning trajectories through a house, for the map-calibration study (paper Sec. IV:
ScanNet-like recordings rather than an agent's 30-degree lattice).

A scan visits the rooms one by one (greedy nearest-next tour over room centres; houses without
room annotations -- user scans -- use farthest-point samples of the free floor instead), walks
there along the string-pulled geodesic path at ``step_m`` per frame with a rate-limited heading,
and looks around at each stop. What makes it realistic for calibration is the *uneven dwell*
of real recordings: each stop makes 1 + Poisson(``extra_turns_mean``) full turns, and the
operator pauses now and then (``pause_prob`` per frame; the pause repeats the pose for a
geometric number of frames with a few millimetres of hand jitter). Repeated, near-identical
frames are exactly what makes Recursive Bayesian Updating over-count evidence.

The scan cycles through new tours until ``frames`` poses exist (or ends after ``tours`` tours).
Everything is seeded.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from calnav.common.ranges import Range, check_ranges

# 2: lengths the same on every CPU (plane_length); in the identity of every cached scan, so a
# scan walked with a CPU's own rounding is made again
TRAJECTORY_VERSION = 2


# Size-like keys of a calibration scan (``scan``), and why their bounds: a hand-held walk moves
# up to 2 m per frame (a longer stride skips rooms; as ``env.dataset.scanning.step_m``, which
# builds one), its hand jitters by less than 0.5 m, and its look-around stops lie within 20 m of
# each other (a house is ~20 m long; 0 = one per room centre).
SCAN_RANGES = {
    "step_m": Range(0.0, 2.0, "metres", lo_open=True),
    "jitter_m": Range(0.0, 0.5, "metres"),
    "stop_spacing_m": Range(0.0, 20.0, "metres"),
}


@dataclass
class ScanConfig:
    frames: int = 300               # poses per scan, frames
    step_m: float = 0.12            # walking distance per frame, metres
    max_turn_deg: float = 12.0      # heading change per frame, walking and looking around, degrees
    extra_turns_mean: float = 0.6   # extra full look-around turns per stop, Poisson mean, turns
    pause_prob: float = 0.04        # chance per frame that the operator pauses, probability
    pause_mean_frames: float = 8.0  # mean pause length (geometric), frames
    jitter_m: float = 0.005         # hand jitter during a pause, metres (std)
    jitter_deg: float = 0.5         # hand jitter of heading and pitch, degrees (std)
    pitch_deg: float = 0.0          # mean camera pitch, degrees (positive looks up)
    pitch_std_deg: float = 4.0      # slow pitch wander while scanning, degrees (std)
    stop_spacing_m: float = 0.0     # look-around stops this far apart over the free floor, metres (0 = one per room centre)
    tours: int = 0                  # tours of all stops, then the scan ends (0 = tour again until `frames`), tours
    up_turn_prob: float = 0.0       # chance that a stop ends with one more turn looking up (ceilings, upper walls), probability
    up_pitch_deg: float = 30.0      # mean camera pitch of those turns, degrees (positive looks up)

    def __post_init__(self) -> None:
        if self.frames < 1:
            raise ValueError(f"scan.frames must be >= 1, got {self.frames}")
        check_ranges(self, "scan", SCAN_RANGES)
        for name in ("step_m", "max_turn_deg", "pause_mean_frames"):
            if not getattr(self, name) > 0:
                raise ValueError(f"scan.{name} must be > 0, got {getattr(self, name)}")
        if not 0 <= self.pause_prob < 1:
            raise ValueError(f"scan.pause_prob must be in [0, 1), got {self.pause_prob}")
        if not min(self.extra_turns_mean, self.jitter_m, self.jitter_deg, self.pitch_std_deg, self.stop_spacing_m) >= 0:
            raise ValueError("scan.extra_turns_mean, jitter_m, jitter_deg, pitch_std_deg and stop_spacing_m must be >= 0")
        if not 0 <= self.tours <= 1000:
            raise ValueError(f"scan.tours must be in [0, 1000], got {self.tours}")
        if not 0 <= self.up_turn_prob <= 1:
            raise ValueError(f"scan.up_turn_prob must be in [0, 1], got {self.up_turn_prob}")
        if not -80 <= self.up_pitch_deg <= 80:
            raise ValueError(f"scan.up_pitch_deg must be in [-80, 80], got {self.up_pitch_deg}")


def _stops(scene, navgrid, rng: np.random.Generator, n_fallback: int = 6, spacing_m: float = 0.0) -> np.ndarray:
    """(n, 2) navigable world points to visit: the free cell nearest each room centre, or
    farthest-point samples of the free floor when the scene has no rooms; with ``spacing_m`` > 0
    farthest-point samples until every free cell is within ``spacing_m`` of a stop (a thorough
    scan: every part of the floor is seen from close by)."""
    free = np.argwhere(navgrid.navigable)
    if len(free) == 0:
        raise ValueError(f"scene {scene.name!r} has no navigable floor to scan")
    free_xy = navgrid.to_world(free)
    if spacing_m > 0:
        return _farthest_points(free_xy, rng, spacing_m=spacing_m)
    if scene.rooms:
        centres = np.array([[(r.xmin + r.xmax) / 2, (r.ymin + r.ymax) / 2] for r in scene.rooms])
        idx = [int(np.argmin(np.linalg.norm(free_xy - c, axis=1))) for c in centres]
        return free_xy[sorted(set(idx), key=idx.index)]
    return _farthest_points(free_xy, rng, count=n_fallback)


def _farthest_points(points: np.ndarray, rng: np.random.Generator, count: int | None = None,
                     spacing_m: float = 0.0) -> np.ndarray:
    """Farthest-point samples of ``points`` (N, 2) from a random first one: ``count`` of them, or
    (count None) until every point lies within ``spacing_m`` of a sample."""
    picks = [int(rng.integers(len(points)))]
    d = np.linalg.norm(points - points[picks[0]], axis=1)
    while len(picks) < count if count is not None else d.max() > spacing_m:
        picks.append(int(np.argmax(d)))
        d = np.minimum(d, np.linalg.norm(points - points[picks[-1]], axis=1))
    return points[picks]


def plane_length(v: np.ndarray) -> float:
    """|v| of a 2-vector v = (x, y), metres, with the same bits on every CPU: sqrt(fma(y, y, x * x))
    with the fused multiply-add done exactly (rationals, rounded once). ``np.linalg.norm`` of a 1-D
    vector is the square root of a BLAS dot, rounded as the kernel OpenBLAS picks for the CPU
    rounds (its AVX-512 kernel fuses the second product, its Haswell and generic ones do not): a
    walk's segment at an exact multiple of ``step_m`` then got one pose more or one less, and every
    later draw of the scan moved. The fused form is the AVX-512 kernel's, the rounding the
    committed scans were walked with, so they stay as they are."""
    x, y = float(v[0]), float(v[1])
    return math.sqrt(float(Fraction(y) * Fraction(y) + Fraction(x * x)))


def _tour(stops: np.ndarray, start: np.ndarray, rng: np.random.Generator) -> list[np.ndarray]:
    """Greedy nearest-next order with a random tie-break of near-equal choices."""
    left = list(range(len(stops)))
    here, order = start, []
    while left:
        d = np.array([plane_length(stops[i] - here) for i in left]) + rng.uniform(0, 0.5, len(left))
        i = left.pop(int(np.argmin(d)))
        order.append(stops[i])
        here = stops[i]
    return order


class _Recorder:
    """Accumulates poses with pauses, jitter and a wandering pitch."""

    def __init__(self, cfg: ScanConfig, height: float, rng: np.random.Generator):
        self.cfg, self.height, self.rng = cfg, height, rng
        self.poses: list[np.ndarray] = []
        self.pitch = 0.0

    @property
    def full(self) -> bool:
        return len(self.poses) >= self.cfg.frames

    def add(self, xy: np.ndarray, yaw: float, mean_pitch_deg: float | None = None) -> None:
        """One pose (and a pause now and then); the pitch wanders about ``mean_pitch_deg``
        (default ``cfg.pitch_deg``)."""
        from calnav.envs.render import camera_pose   # here: ScanConfig (a config section) loads without Open3D

        cfg, rng = self.cfg, self.rng
        self.pitch = 0.9 * self.pitch + math.sqrt(1 - 0.81) * rng.normal(0, cfg.pitch_std_deg)  # AR(1) wander
        mean = cfg.pitch_deg if mean_pitch_deg is None else mean_pitch_deg
        pitch = math.radians(mean + self.pitch)
        self.poses.append(camera_pose(xy, yaw, self.height, pitch))
        if rng.random() < cfg.pause_prob:
            for _ in range(int(rng.geometric(1.0 / cfg.pause_mean_frames))):
                if self.full:
                    return
                j_xy = xy + rng.normal(0, cfg.jitter_m, 2)
                j_yaw = yaw + math.radians(rng.normal(0, cfg.jitter_deg))
                j_pitch = pitch + math.radians(rng.normal(0, cfg.jitter_deg))
                self.poses.append(camera_pose(j_xy, j_yaw, self.height, j_pitch))


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def scan_poses(scene, navgrid, env_cfg, cfg: ScanConfig | None = None, seed: int = 0) -> np.ndarray:
    """(frames, 4, 4) float64 world-from-camera poses of a room-by-room hand-held scan.

    scene: ``envs.scene.Scene``; navgrid: its ``NavGrid``; env_cfg: ``EnvConfig`` (camera
    height). The camera sits at floor_z + ``env_cfg.camera_height_m``.
    """
    cfg = cfg or ScanConfig()
    rng = np.random.default_rng(seed)
    stops = _stops(scene, navgrid, rng, spacing_m=cfg.stop_spacing_m)
    rec = _Recorder(cfg, float(scene.floor_z) + env_cfg.camera_height_m, rng)
    turn = math.radians(cfg.max_turn_deg)
    xy = stops[int(rng.integers(len(stops)))].copy()
    yaw = float(rng.uniform(-math.pi, math.pi))
    tours = 0
    while not rec.full and (cfg.tours == 0 or tours < cfg.tours):
        tours += 1
        for target in _tour(stops, xy, rng):
            if rec.full:
                break
            goal = np.zeros(navgrid.navigable.shape, dtype=bool)
            goal[tuple(navgrid.to_cell(target[None])[0])] = True
            try:
                path = navgrid.geodesic_field(goal).path(xy)
            except ValueError:   # a room unreachable from here: skip it
                continue
            for a, b in zip(path[:-1], path[1:]):
                seg = plane_length(b - a)   # decides how many poses the segment gets: the same on every CPU
                heading = math.atan2(b[1] - a[1], b[0] - a[0])
                for s in np.arange(cfg.step_m, seg + cfg.step_m, cfg.step_m):
                    if rec.full:
                        break
                    yaw += float(np.clip(_wrap(heading - yaw), -turn, turn))
                    xy = a + (b - a) * min(s / seg, 1.0) if seg > 0 else b.copy()
                    rec.add(xy, yaw)
            turns = 1 + int(rng.poisson(cfg.extra_turns_mean))
            direction = 1.0 if rng.random() < 0.5 else -1.0
            # drawn only when enabled, so up_turn_prob=0 draws exactly the random numbers it always did
            up = cfg.up_turn_prob > 0 and rng.random() < cfg.up_turn_prob
            pitches = ([None] * int(round(turns * 2 * math.pi / turn))
                       + [cfg.up_pitch_deg] * (int(round(2 * math.pi / turn)) if up else 0))
            for pitch in pitches:
                if rec.full:
                    break
                yaw += direction * turn
                rec.add(xy, yaw, pitch)
    if not rec.poses:
        raise ValueError(f"scene {scene.name!r}: no scan stop is reachable from another")
    return np.stack(rec.poses[: cfg.frames])
