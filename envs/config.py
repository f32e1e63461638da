"""Typed configuration of the simulator and task (loaded from YAML by ``eval.config``)."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal

from calnav.common.ranges import Range, check_ranges
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
# Scenes per split at most: ``envs.scenes.SPLIT_BLOCK``, the seeds of one split's block (a test
# keeps them equal; envs.scenes imports this module, so the constant cannot be imported from it).
MAX_SCENES_PER_SPLIT = 1_000_000
# Largest distance of the task, metres: no start lies farther than 1 km from its goal in any
# building (calnav's houses are at most ~20 m long, HM3D's longest episodes ~30 m of geodesic).
MAX_TASK_DISTANCE_M = 1000.0
METRES = "metres"

# Size-like keys of the dataset (``env.dataset``), and why their bounds:
DATASET_RANGES = {
    # start-to-goal geodesic bounds: 0 = any start, up to the task's largest distance
    "min_geodesic_m": Range(0.0, MAX_TASK_DISTANCE_M, METRES),
    "max_geodesic_m": Range(0.0, MAX_TASK_DISTANCE_M, METRES, lo_open=True),
    # geodesic / euclidean is >= 1 by the triangle inequality, so 1 keeps every episode; above 10
    # every start would have to lie behind a maze of walls
    "min_euclid_ratio": Range(1.0, 10.0),
    # an island radius of 0 keeps every island; 100 m is wider than any building
    "min_island_radius_m": Range(0.0, 100.0, METRES),
    "train_scenes": Range(0, MAX_SCENES_PER_SPLIT, "houses"),
    "val_scenes": Range(0, MAX_SCENES_PER_SPLIT, "houses"),
    "test_scenes": Range(0, MAX_SCENES_PER_SPLIT, "houses"),
    "calib_scenes": Range(0, MAX_SCENES_PER_SPLIT, "houses"),
    # a house yields at least one episode (0 would reject every house of the split); 10,000 per
    # house is beyond any benchmark (HM3D: ~50 per scene in val)
    "episodes_per_scene": Range(1, 10_000, "episodes"),
    "oracle_max_steps": Range(1, 100_000, "actions"),
    # how far a habitat-lab episode's start may move onto calnav's navmesh: habitat-sim's and
    # calnav's navmeshes differ by centimetres; beyond 2 m (habitat-sim's own snap box) it is
    # another task
    "max_snap_m": Range(0.0, 2.0, METRES),
    # one storey is every calnav house before storeys existed; three keep a house's stairs and
    # floors within the ~9 m that the renderer's and the map's height ranges were sized for
    "storeys": Range(1, 3, "storeys"),
}

# Size-like keys of the agent, its sensor and its task (``env``), and why their bounds:
ENV_RANGES = {
    # the camera stands inside one storey (calnav's walls are 2.5-3 m high; HM3D's camera 0.88 m);
    # below 5 cm it would look along the floor
    "camera_height_m": Range(0.05, 3.0, METRES),
    # depth range: above 0 (a pinhole sees nothing at 0) and within 100 m (beyond any indoor
    # sensor; HM3D's is 0.5-5 m): the voxel map's per-frame table covers the frustum up to it
    "min_depth_m": Range(0.0, 100.0, METRES, lo_open=True),
    "max_depth_m": Range(0.0, 100.0, METRES, lo_open=True),
    # a step of 1 cm (the smallest move a depth sensor tells from its noise) to 2 m (beyond the
    # stride of any indoor robot; HM3D's is 0.25 m)
    "forward_step_m": Range(0.01, 2.0, METRES),
    # the body: a radius of 2 cm (below, the 5 cm grid sees a point) to 1 m (wider passes no
    # doorway: calnav's are 0.9-1 m), a height from a toy robot to a storey
    "agent_radius_m": Range(0.02, 1.0, METRES),
    "agent_height_m": Range(0.1, 3.0, METRES),
    # the navigation grid: 5 mm resolves every passage a 2 cm body fits through (finer cells only
    # cost memory: (house extent / cell)^2 cells, checked by the preflight); 0.5 m cells are wider
    # than half a doorway, which would close
    "nav_cell_m": Range(0.005, 0.5, METRES),
    # success and view-point radii: above 0 (a point is never reached) and within 10 m (farther
    # is not "at" the object in any room)
    "success_distance_m": Range(0.0, 10.0, METRES, lo_open=True),
    "view_point_radius_m": Range(0.0, 10.0, METRES, lo_open=True),
}


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
    data_path: str = ""              # habitat-lab ObjectNav episode file, {split} for the split (HM3D / MP3D); "" = generated episodes
    max_snap_m: float = 0.5          # a file's start farther than this from calnav's navmesh is refused, metres
    storeys: int = 1                 # storeys per procedural house, joined by staircases (envs.stairs), storeys

    # Left out of every key, fingerprint and saved config while at these values (``plain_dict``):
    # the keys and records made before the fields existed stay valid.
    OMIT_AT_DEFAULT: ClassVar[dict[str, Any]] = {"data_path": "", "max_snap_m": 0.5, "storeys": 1}

    def __post_init__(self) -> None:
        check_ranges(self, "env.dataset", DATASET_RANGES)
        if not isinstance(self.data_path, str):
            raise ValueError(f"env.dataset.data_path must be a path (str), got {self.data_path!r}")
        if self.data_path and not self.scene_dir:
            raise ValueError(f"env.dataset.data_path {self.data_path!r} needs env.dataset.scene_dir: the folder its "
                             "scene ids resolve under (habitat-lab's scenes_dir, e.g. data/scene_datasets)")
        if self.storeys > 1 and (self.scene_dir or self.style == "scanned"):
            raise ValueError(f"env.dataset.storeys={self.storeys} builds calnav's procedural houses with stairs; it "
                             f"does not apply to {'user scenes (env.dataset.scene_dir)' if self.scene_dir else 'scans'}"
                             ": use storeys=1 there")
        if not self.min_geodesic_m < self.max_geodesic_m:
            raise ValueError(f"env.dataset.max_geodesic_m ({self.max_geodesic_m:g} m) must be above "
                             f"env.dataset.min_geodesic_m ({self.min_geodesic_m:g} m): no start distance lies between "
                             "them, so every episode drawn would be rejected")
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
        check_ranges(self, "env", ENV_RANGES)
        if not self.min_depth_m < self.max_depth_m:
            raise ValueError(f"need 0 < env.min_depth_m < env.max_depth_m, got {self.min_depth_m}, {self.max_depth_m}")
        count_key = f"{self.split}_scenes"
        if not self.dataset.scene_dir and getattr(self.dataset, count_key) < 1:
            raise ValueError(f"env.split={self.split} has no houses: env.dataset.{count_key} is "
                             f"{getattr(self.dataset, count_key)}; set env.dataset.{count_key} >= 1 or pick another "
                             "env.split")
        for key in ("turn_angle_deg", "tilt_angle_deg"):
            if not 0 < getattr(self, key) <= 180:
                raise ValueError(f"env.{key} must be in (0, 180] degrees, got {getattr(self, key)}")
        for key in ("rgb_noise_std", "depth_noise_std"):
            if not getattr(self, key) >= 0:
                raise ValueError(f"env.{key} must be >= 0, got {getattr(self, key)}")
        if self.max_episode_steps < 1:
            raise ValueError(f"env.max_episode_steps must be >= 1 actions, got {self.max_episode_steps}")


def require_single_storey(env_cfg: EnvConfig, what: str) -> None:
    """Refuse a house with storeys where ``what`` (a command or a simulator front end) only
    knows one storey, naming what does run them (the gym env behind ``calnav objectnav``)."""
    if env_cfg.dataset.storeys > 1:
        raise ValueError(f"{what} runs single-storey houses only; env.dataset.storeys={env_cfg.dataset.storeys} "
                         "runs in calnav objectnav (calnav's gym env): use env.dataset.storeys=1 here")


def plain_dict(obj) -> Any:
    """``dataclasses.asdict`` of a config, without the fields a config class lists in its
    ``OMIT_AT_DEFAULT`` while they hold those values (cache keys, fingerprints, saved configs)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        omit = getattr(type(obj), "OMIT_AT_DEFAULT", {})
        return {f.name: plain_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)
                if not (f.name in omit and getattr(obj, f.name) == omit[f.name])}
    if isinstance(obj, (list, tuple)):
        return type(obj)(plain_dict(x) for x in obj)
    if isinstance(obj, dict):
        return {k: plain_dict(v) for k, v in obj.items()}
    return obj
