"""Configuration of the map-calibration experiment (``calnav calibrate-map``,
``configs/calibrate_map.yaml``): which houses, how they are scanned, which segmenters,
strategies and calibration methods are compared, and how the fits run."""
from __future__ import annotations

from dataclasses import dataclass, field

from agent.config import SegmenterName
from envs.config import EnvConfig
from envs.trajectories import ScanConfig
from eval.config import RunConfig
from mapping.config import FUSION_NAMES, MappingConfig
from mapping.calibration.glfs_train import GLFSTrainConfig
from mapping.sequences import SequenceConfig
from eval.sequence.config import SequenceSetConfig

CALIBRATIONS: tuple[str, ...] = ("none", "temperature_2d", "temperature_3d", "vector_3d")
LEARNED_SEGMENTERS: tuple[str, ...] = ("learned_rgb", "learned_rgbd")


@dataclass
class StudyConfig:
    """What is compared and on which houses. Calibration-train and -validation houses are the
    first ``calib_train_scenes`` and the next ``calib_val_scenes`` of the ``calib`` split
    (seeds disjoint from every other split); test houses are the first ``test_scenes`` of the
    ``test`` split (or the user scene folders train/val/test when env.dataset.scene_dir is set)."""

    segmenters: list[SegmenterName] = field(default_factory=lambda: list(LEARNED_SEGMENTERS))  # learned_rgb | learned_rgbd (gt | noisy also work)
    strategies: list[str] = field(default_factory=lambda: list(FUSION_NAMES))  # fusion strategies compared
    calibrations: list[str] = field(default_factory=lambda: list(CALIBRATIONS))  # none | temperature_2d | temperature_3d | vector_3d
    calib_train_scenes: int = 12     # houses the temperatures and GLFS are fitted on
    calib_val_scenes: int = 4        # houses for GLFS early stopping
    test_scenes: int = 12            # houses every method is scored on
    cache_cap: int = 1000            # observations kept per voxel (uniform subsample beyond), count (authors: 1000)
    pixels_per_frame: int = 64       # labelled pixels sampled per frame for 2D scaling and pixel mECE, count
    fit_max_voxels: int = 30000      # voxels (random subset of calibration-train) scored per 3D search step, count
    grid_points: int = 21            # 3D temperature search: log-spaced grid points over [0.01, 200]
    refine_iters: int = 10           # 3D temperature search: golden-section iterations after the grid
    vector_sweeps: int = 2           # 3D vector scaling: coordinate-descent sweeps over the classes
    vector_refine_iters: int = 6     # 3D vector scaling: golden-section iterations per class and sweep
    glfs_max_voxels: int = 200000    # GLFS training voxels (random subset of calibration-train), count

    def __post_init__(self) -> None:
        for name in self.strategies:
            if name not in FUSION_NAMES:
                raise ValueError(f"unknown fusion strategy {name!r}; valid names: {', '.join(FUSION_NAMES)}")
        for name in self.calibrations:
            if name not in CALIBRATIONS:
                raise ValueError(f"unknown calibration {name!r}; valid names: {', '.join(CALIBRATIONS)}")
        if not self.segmenters or not self.strategies:
            raise ValueError("study.segmenters and study.strategies must not be empty")
        if min(self.calib_train_scenes, self.calib_val_scenes, self.test_scenes) < 1:
            raise ValueError("study.calib_train_scenes, calib_val_scenes and test_scenes must be >= 1")
        if min(self.cache_cap, self.pixels_per_frame, self.fit_max_voxels, self.glfs_max_voxels) < 1:
            raise ValueError("study.cache_cap, pixels_per_frame, fit_max_voxels and glfs_max_voxels must be >= 1")


@dataclass
class CalibrateMapConfig:
    """``configs/calibrate_map.yaml``."""

    env: EnvConfig = field(default_factory=EnvConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    run: RunConfig = field(default_factory=RunConfig)
    scan: ScanConfig = field(default_factory=ScanConfig)
    study: StudyConfig = field(default_factory=StudyConfig)
    glfs: GLFSTrainConfig = field(default_factory=GLFSTrainConfig)
    sequences: SequenceSetConfig = field(default_factory=SequenceSetConfig)  # recorded sequences instead of houses
    sequence: SequenceConfig = field(default_factory=SequenceConfig)      # how recorded sequences are read
