"""Typed configuration of the simulator and task (loaded from YAML by ``eval.config``)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

SplitName = Literal["train", "val", "test"]


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
    scene_dir: str = ""              # directory of user scenes (*.npz / *.ply); "" = procedural houses


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
    obstacle_min_height_m: float = 0.1        # obstacles start this far above the floor, metres
    nav_cell_m: float = 0.05                  # navigation grid cell size, metres
    max_episode_steps: int = 500              # episode ends after this many actions
    success_distance_m: float = 0.1           # Success needs DistanceToGoal below this, metres
    view_point_radius_m: float = 1.0          # goal view points lie within this of the object, metres
    dataset: DatasetConfig = field(default_factory=DatasetConfig)

    def __post_init__(self) -> None:
        w, h = self.resolution
        if w < 8 or h < 8:
            raise ValueError(f"env.resolution must be at least 8x8 pixels, got {w}x{h}")
        if not 0 < self.hfov_deg < 180:
            raise ValueError(f"env.hfov_deg must be in (0, 180), got {self.hfov_deg}")
        if not 0 < self.min_depth_m < self.max_depth_m:
            raise ValueError(f"need 0 < env.min_depth_m < env.max_depth_m, got {self.min_depth_m}, {self.max_depth_m}")
