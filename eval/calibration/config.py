"""Configuration of the map-calibration experiment (``calnav calibrate-map``,
``configs/calibrate_map.yaml``): which houses, how they are scanned, which segmenters,
strategies and calibration methods are compared, and how the fits run."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from calnav.agent.segmenters import check_segmenter_spec
from calnav.agent.segmenters.base import SegmenterConfig
from calnav.envs.config import MAX_RESOLUTION_PX, EnvConfig
from calnav.envs.trajectories import ScanConfig
from calnav.eval.config import RunConfig, build_dataclass, to_dict
from calnav.mapping.config import FUSION_NAMES, MappingConfig
from calnav.mapping.calibration.glfs_train import GLFSTrainConfig
from calnav.mapping.sequences import LayoutName, SequenceConfig

CALIBRATIONS: tuple[str, ...] = ("none", "temperature_2d", "temperature_3d", "vector_3d")
LEARNED_SEGMENTERS: tuple[str, ...] = ("learned_rgb", "learned_rgbd")
TAU_CURVE_RANGE = (0.01, 300.0)   # the mECE-vs-temperature curve's span (authors' RBU optimum: 80-131)


@dataclass
class SequenceSetConfig:
    """Recorded sequences replacing calnav's houses in ``calnav calibrate-map``."""

    list: str = ""                   # list file, one "<role> <dir> [layout]" per line (role: calib_train | calib_val | test); "" = calnav houses
    layout: LayoutName = "scannet"   # layout of listed sequences that name none: scannet | 7scenes


@dataclass
class GLFSVariant:
    """One GLFS row of the study: ``name`` (the row's calibration label and file name) and
    ``overrides`` of the ``glfs:`` section (GLFSTrainConfig keys)."""

    name: str
    overrides: dict[str, Any] = field(default_factory=dict)


def default_glfs_variants() -> list[GLFSVariant]:
    """calnav's rule, the authors' rule, the constrained rule, an unweighted NLL, the constrained
    rule from the geometric mean (G = 1), both with 10x smaller steps, the authors' set-up."""
    return [GLFSVariant("learned", {}), GLFSVariant("val_miou", {"selection": "val_miou"}),
            GLFSVariant("constrained", {"selection": "constrained"}),
            GLFSVariant("unweighted", {"class_weighting": "none", "selection": "constrained"}),
            GLFSVariant("geo_constrained", {"init_g": 1.0, "selection": "constrained", "val_per_epoch": 3}),
            GLFSVariant("constrained_slow", {"selection": "constrained", "lr": 0.005, "val_per_epoch": 3,
                                             "patience": 6}),
            GLFSVariant("geo_constrained_slow", {"init_g": 1.0, "selection": "constrained", "lr": 0.005,
                                                 "val_per_epoch": 3, "patience": 6}),
            GLFSVariant("authors", {"learn_gates": False, "init_g": 0.0, "init_eps": 0.0, "init_tau": 0.4,
                                    "selection": "val_miou", "patience": 5, "val_per_epoch": 3, "grad_clip": 1.0})]


@dataclass
class StudyConfig:
    """What is compared and on which houses. Calibration-train and -validation houses are the
    first ``calib_train_scenes`` and the next ``calib_val_scenes`` of the ``calib`` split
    (seeds disjoint from every other split); test houses are the first ``test_scenes`` of the
    ``test`` split (or the user scene folders train/val/test when env.dataset.scene_dir is set)."""

    segmenters: list[str] = field(default_factory=lambda: list(LEARNED_SEGMENTERS))  # learned_rgb | learned_rgbd (any agent.segmenter spec works: gt, hf, a plugin, ...)
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
    glfs_variants: list[GLFSVariant] = field(default_factory=default_glfs_variants)  # GLFS rows: name + glfs overrides
    tau_curve_points: int = 41       # mECE-vs-temperature curve: log-spaced temperatures over TAU_CURVE_RANGE, points
    figure_scene: int = 0            # qualitative figures: index of the test house, count from 0
    figure_views: int = 3            # qualitative figures: camera views rendered, count
    figure_resolution: tuple[int, int] = (320, 240)  # qualitative figures: rendered view WxH, pixels
    authors_miou_exclude: list[int] = field(default_factory=list)  # class ids left out of the authors'-convention mIoU

    def __post_init__(self) -> None:
        for name in self.segmenters:
            check_segmenter_spec(name)
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
        if self.grid_points < 2 or self.refine_iters < 0 or self.vector_sweeps < 0 or self.vector_refine_iters < 0:
            raise ValueError(f"study.grid_points must be >= 2 (got {self.grid_points}); refine_iters, vector_sweeps "
                             "and vector_refine_iters >= 0")
        if "glfs" in self.strategies and not self.glfs_variants:
            raise ValueError("study.glfs_variants must name at least one variant when glfs is compared")
        names = [v.name for v in self.glfs_variants]
        for n in names:
            if not n.replace("_", "").isalnum():
                raise ValueError(f"study.glfs_variants: name {n!r} must be letters, digits and _ (it names files)")
        if len(set(names)) != len(names):
            raise ValueError(f"study.glfs_variants: names must be unique, got {names}")
        if self.tau_curve_points < 3 or self.figure_views < 1:
            raise ValueError("study.tau_curve_points must be >= 3 and figure_views >= 1")
        w, h = self.figure_resolution
        if not (8 <= w <= MAX_RESOLUTION_PX and 8 <= h <= MAX_RESOLUTION_PX):   # rendered like the sensor's
            raise ValueError(f"study.figure_resolution must be between 8x8 and {MAX_RESOLUTION_PX}x{MAX_RESOLUTION_PX} "
                             f"pixels, got {w}x{h}")
        if self.figure_scene < 0 or self.figure_scene >= self.test_scenes:
            raise ValueError(f"study.figure_scene must index a test house, in [0, {self.test_scenes}), "
                             f"got {self.figure_scene}")


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
    segmenter: SegmenterConfig = field(default_factory=SegmenterConfig)   # settings of the segmenters (model, label_map, ...)

    def __post_init__(self) -> None:
        self.glfs_configs()    # a bad variant is refused at load time, before anything is written

    def glfs_configs(self) -> dict[str, GLFSTrainConfig]:
        """{variant name: the ``glfs`` section with the variant's overrides}."""
        base = to_dict(self.glfs)
        out = {}
        for v in self.study.glfs_variants:
            out[v.name] = build_dataclass(GLFSTrainConfig, {**base, **v.overrides},
                                          prefix=f"study.glfs_variants.{v.name}.overrides")
        return out
