"""Typed configuration of the simulator and task (loaded from YAML by ``eval.config``)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from calnav.envs.scanning.config import ScanningConfig

SplitName = Literal["train", "val", "test"]
# Scene styles (``envs.scenes.STYLES``; a test keeps them equal): the procedural house as built,
# or a scan of it (rendered RGB-D with sensor noise, TSDF-fused, labelled from the clean house).
StyleName = Literal["clean", "scanned"]
# Fields of view (degrees, exclusive) the semantic map accepts (``mapping.frame_geometry``
# MIN_FOV_DEG / MAX_FOV_DEG; a test keeps them equal): a camera outside them would be refused
# by the map in the middle of a run.
FOV_BOUNDS_DEG = (1.0, 179.0)


MAX_RESOLUTION_PX = 4096   # largest sensor side, pixels (a 40000x30000 typo fails here, not in an allocation)


@dataclass
class DatasetConfig:
    """Episode dataset: scene seeds per split (disjoint ranges) and episodes per scene."""

    train_scenes: int = 100          # number of procedural houses in the train split
    val_scenes: int = 30             # houses in the val split
    test_scenes: int = 30            # houses in the test split
    calib_scenes: int = 100          # houses of the map-calibration study (calnav calibrate-map), disjoint seeds
    episodes_per_scene: int = 20     # ObjectNav episodes generated per house
    seed: int = 0                    # base seed; split seeds are derived from it, disjoint
    min_geodesic_m: float = 1.0      # shortest allowed start-to-goal geodesic distance, metres
    max_geodesic_m: float = 30.0     # longest allowed start-to-goal geodesic distance, metres
    min_euclid_ratio: float = 1.05   # reject a fraction of "trivial" episodes whose geodesic/euclid ratio is below this
    min_island_radius_m: float = 1.5  # starts only on navmesh islands at least this wide (habitat-lab's ISLAND_RADIUS_LIMIT), metres
    oracle_max_steps: int = 500      # an episode is kept only if the discrete-action oracle solves it in this many actions (HM3D's step limit), actions
    scene_dir: str = ""              # directory of user scenes (*.npz / *.ply); "" = procedural houses
    style: StyleName = "clean"       # procedural houses as built (clean) or reconstructed from a simulated scan (scanned)
    scanning: ScanningConfig = field(default_factory=ScanningConfig)  # scan settings (style scanned only)

    def __post_init__(self) -> None:
        if not 0 <= self.min_island_radius_m <= 100:   # written so that NaN fails too
            raise ValueError(f"dataset.min_island_radius_m must be in [0, 100] metres, got {self.min_island_radius_m}")
        if not 1 <= self.oracle_max_steps <= 100_000:
            raise ValueError(f"dataset.oracle_max_steps must be in [1, 100000] actions, got {self.oracle_max_steps}")
        if self.style not in ("clean", "scanned"):
            raise ValueError(f"unknown dataset.style {self.style!r}; valid choices: clean, scanned")
        if self.style == "scanned" and self.scene_dir:
            raise ValueError(f"dataset.style=scanned scans calnav's procedural houses, but dataset.scene_dir "
                             f"{self.scene_dir!r} holds user scenes, which already are scans: use style=clean "
                             "(the scenes load as they are)")


@dataclass
class NavMeshConfig:
    """How navigable space is computed: habitat-sim's ``NavMeshSettings`` (Recast), geometry only
    (``envs.navmesh``). The agent's height and radius and the cell size are the env's
    ``agent_height_m``, ``agent_radius_m`` and ``nav_cell_m``. Defaults are habitat-sim's but
    for the cell height: at its 0.2 m the 0.88 m agent would count as 1.0 m tall and could climb
    onto 0.38 m coffee tables (heights snap to whole cells)."""

    cell_height_m: float = 0.05             # vertical cell of the heightfield, metres (habitat-sim: 0.2)
    agent_max_climb_m: float = 0.2          # highest step between neighbouring cells the agent walks over, metres
    agent_max_slope_deg: float = 45.0       # steepest walkable surface, degrees from horizontal
    region_min_size: int = 20               # islands of fewer than this^2 cells are dropped, cells (20 = 1 m^2 at 5 cm)
    filter_low_hanging_obstacles: bool = True     # step onto obstacles at most one climb above walkable floor
    filter_ledge_spans: bool = True               # no walking along a drop of more than one climb (hole edges)
    filter_walkable_low_height_spans: bool = True  # the agent must fit under whatever is above

    def __post_init__(self) -> None:
        for key, lo, hi, lo_open, hi_open in (("cell_height_m", 0.001, 1.0, False, False),
                                               ("agent_max_climb_m", 0.0, 2.0, False, False),
                                               ("agent_max_slope_deg", 0.0, 90.0, False, True)):
            v = getattr(self, key)
            ok = (v > lo if lo_open else v >= lo) and (v < hi if hi_open else v <= hi)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and ok):
                raise ValueError(f"env.navmesh.{key} must be in {'(' if lo_open else '['}{lo:g}, {hi:g}"
                                 f"{')' if hi_open else ']'}, got {v!r}")
        if isinstance(self.region_min_size, bool) or not isinstance(self.region_min_size, int) \
                or not 0 <= self.region_min_size <= 1000:
            raise ValueError(f"env.navmesh.region_min_size must be an int in [0, 1000] cells, got {self.region_min_size!r}")


@dataclass
class EnvConfig:
    """Habitat ObjectNav (HM3D 2022) sensor, agent and task settings."""

    split: SplitName = "val"                  # which split's episodes to run
    resolution: tuple[int, int] = (640, 480)  # sensor width x height, pixels ("WxH" on the CLI)
    hfov_deg: float = 79.0                    # horizontal field of view, degrees
    camera_height_m: float = 0.88             # camera height above the floor, metres
    min_depth_m: float = 0.5                  # depth below this is invalid (0), metres
    max_depth_m: float = 5.0                  # depth above this is invalid (0), metres
    normalize_depth: bool = False             # Habitat's normalize_depth: emit (d - min) / (max - min) in [0, 1] instead of metres
    rgb_noise_std: float = 0.0                # Gaussian RGB noise, std in uint8 levels
    depth_noise_std: float = 0.0              # Gaussian depth noise, std in metres per metre of depth
    semantic_sensor: bool = True              # emit ground-truth semantics in observations
    forward_step_m: float = 0.25              # MOVE_FORWARD distance, metres
    turn_angle_deg: float = 30.0              # TURN_LEFT/RIGHT angle, degrees
    tilt_angle_deg: float = 30.0              # LOOK_UP/DOWN angle, degrees
    enable_look: bool = False                 # add LOOK_UP/LOOK_DOWN to the action space
    agent_radius_m: float = 0.18              # agent cylinder radius, metres
    agent_height_m: float = 0.88              # agent cylinder height (obstacle band top), metres
    nav_cell_m: float = 0.05                  # navigation grid cell size (habitat-sim cell_size), metres
    max_episode_steps: int = 500              # episode ends after this many actions
    success_distance_m: float = 0.1           # Success needs DistanceToGoal below this, metres
    view_point_radius_m: float = 1.0          # goal view points lie within this of the object, metres
    navmesh: NavMeshConfig = field(default_factory=NavMeshConfig)  # how navigable space is computed (Recast's rules)
    dataset: DatasetConfig = field(default_factory=DatasetConfig)

    def __post_init__(self) -> None:
        w, h = self.resolution
        if not (8 <= w <= MAX_RESOLUTION_PX and 8 <= h <= MAX_RESOLUTION_PX):
            raise ValueError(f"env.resolution must be between 8x8 and {MAX_RESOLUTION_PX}x{MAX_RESOLUTION_PX} "
                             f"pixels, got {w}x{h}")
        lo, hi = FOV_BOUNDS_DEG
        if not lo < self.hfov_deg < hi:
            raise ValueError(f"env.hfov_deg must be in ({lo:g}, {hi:g}) degrees, got {self.hfov_deg}")
        vfov = math.degrees(2 * math.atan(math.tan(math.radians(self.hfov_deg) / 2) * h / w))
        if not lo < vfov < hi:
            raise ValueError(f"env.hfov_deg = {self.hfov_deg} at {w}x{h} gives a vertical field of view of "
                             f"{vfov:.3g} deg, outside ({lo:g}, {hi:g}); use a wider view or a taller image")
        if not 0 < self.min_depth_m < self.max_depth_m:
            raise ValueError(f"need 0 < env.min_depth_m < env.max_depth_m, got {self.min_depth_m}, {self.max_depth_m}")
        if not 0.005 <= self.nav_cell_m <= 0.5:   # written so that NaN fails too
            raise ValueError(f"env.nav_cell_m must be in [0.005, 0.5] metres, got {self.nav_cell_m}")
        for key in ("camera_height_m", "forward_step_m", "agent_radius_m", "agent_height_m",
                    "success_distance_m", "view_point_radius_m"):
            if not getattr(self, key) > 0:   # written so that NaN fails too
                raise ValueError(f"env.{key} must be > 0 metres, got {getattr(self, key)}")
        for key in ("turn_angle_deg", "tilt_angle_deg"):
            if not 0 < getattr(self, key) <= 180:
                raise ValueError(f"env.{key} must be in (0, 180] degrees, got {getattr(self, key)}")
        for key in ("rgb_noise_std", "depth_noise_std"):
            if not getattr(self, key) >= 0:
                raise ValueError(f"env.{key} must be >= 0, got {getattr(self, key)}")
        if self.max_episode_steps < 1:
            raise ValueError(f"env.max_episode_steps must be >= 1 actions, got {self.max_episode_steps}")
