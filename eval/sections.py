"""The config sections the experiments own, as sections of the one root config
(``eval.config.Config``): ``study`` / ``sequences`` (the map-calibration study, ``calnav
calibrate-map`` / ``fit-glfs`` / ``export-sequence``), ``data`` / ``train`` (``calnav
train-segmenter`` / ``eval-segmenter``) and ``predictor_train`` (``calnav train-predictor``).

They live here, in a shared module, because the root config holds them: the experiment
subpackages import the shared modules, never the other way round. Like every section they are
plain dataclasses (the validation settings are attached in ``eval.config``) that import nothing
heavy, so loading a config stays fast.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from calnav.agent.segmenters import check_segmenter_spec
from calnav.common.ranges import Range, check_ranges
from calnav.envs.config import MAX_RESOLUTION_PX
from calnav.mapping.registry import FUSIONS, LAYOUTS

# ------------------------------------------------------------------ the map-calibration study
CALIBRATIONS: tuple[str, ...] = ("none", "temperature_2d", "temperature_3d", "vector_3d")
LEARNED_SEGMENTERS: tuple[str, ...] = ("learned_rgb", "learned_rgbd")
TAU_CURVE_RANGE = (0.01, 300.0)   # the mECE-vs-temperature curve's span (authors' RBU optimum: 80-131)
# ``calibrate-map --quick``: a <= 5 minute smoke run of the whole pipeline on 2 cores, as the
# (key, value) pairs the flag sets (the shorthand ``calibrate-map --quick``, declared in ``eval.calibration.study``)
QUICK_PRESET: tuple[tuple[str, Any], ...] = (
    ("study.calib_train_scenes", 3), ("study.calib_val_scenes", 1), ("study.test_scenes", 3), ("scan.frames", 200),
    ("study.fit_max_voxels", 8000), ("study.grid_points", 11), ("study.refine_iters", 5), ("study.vector_sweeps", 1),
    ("study.vector_refine_iters", 3), ("study.glfs_max_voxels", 20000), ("glfs.epochs", 4), ("glfs.patience", 2),
    ("study.tau_curve_points", 13),
)


@dataclass
class SequenceSetConfig:
    """Recorded sequences replacing calnav's houses in ``calnav calibrate-map`` (``sequences``)."""

    list: str = ""                   # list file, one "<role> <dir> [layout]" per line (role: calib_train | calib_val | test); "" = calnav houses
    layout: str = "scannet"          # layout of listed sequences that name none (mapping.registry.LAYOUTS): scannet | 7scenes

    def __post_init__(self) -> None:
        LAYOUTS.check(self.layout)


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
class CalibrationStudyConfig:
    """What the map-calibration study compares and on which houses (``study``).
    Calibration-train and -validation houses are the first ``calib_train_scenes`` and the next
    ``calib_val_scenes`` of the ``calib`` split (seeds disjoint from every other split); test
    houses are the first ``test_scenes`` of the ``test`` split (or the user scene folders
    train/val/test when env.dataset.scene_dir is set)."""

    segmenters: list[str] = field(default_factory=lambda: list(LEARNED_SEGMENTERS))  # learned_rgb | learned_rgbd (any agent.segmenter spec works: gt, hf, a plugin, ...)
    strategies: list[str] = field(default_factory=lambda: list(FUSIONS.names()))  # fusion strategies compared
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
            if not isinstance(name, str) or name not in FUSIONS:
                raise ValueError(f"unknown {FUSIONS.kind} {name!r} in study.strategies; valid choices: "
                                 f"{', '.join(FUSIONS.names())}")
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


# ------------------------------------------------------------------ segmenter training
EVAL_APPEARANCES: tuple[str, ...] = ("none", "camera", "recolour")   # data.eval_appearance (eval.segmenter.appearance)

@dataclass
class SegDataConfig:
    """Which frames are rendered (``data``; ``eval.segmenter.data`` renders them)."""

    frames: int = 20000              # training frames rendered (eval: --frames)
    scenes: int = 0                  # houses of the split used; 0 = all (env.dataset.<split>_scenes)
    resolution: tuple[int, int] = (160, 120)  # rendered frame WxH, pixels (the training resolution)
    walk_steps: int = 10             # frames per random walk
    turn_prob: float = 0.4           # probability a walk step turns (else moves forward)
    pitch_jitter_deg: float = 2.0    # camera pitch std, degrees
    seed: int = 0                    # pose sampling seed (eval adds EVAL_SEED_OFFSET)
    min_object_fraction: float = 0.03  # training frames with fewer non-structure (object) pixels than this ...
    keep_sparse_prob: float = 0.3    # ... are kept with this probability (1 = no rebalancing; eval never rebalances)
    scanned_fraction: float = 0.5    # share of each house's training frames rendered from its scan, [0, 1]
                                     # (validation / evaluation frames follow env.dataset.style)
    recolour_fraction: float = 0.0   # share of each training house's instances recoloured and repatterned, [0, 1]
                                     # (eval.segmenter.appearance; validation / evaluation frames keep their colours)
    eval_appearance: Literal["none", "camera", "recolour"] = "none"  # eval-segmenter frames: as rendered, through
                                     # the fixed camera shift of eval.segmenter.appearance (not the training levers'
                                     # distribution), or of houses with every instance recoloured (novel colours)

    def __post_init__(self) -> None:
        if self.eval_appearance not in EVAL_APPEARANCES:
            raise ValueError(f"unknown data.eval_appearance {self.eval_appearance!r}; valid choices: "
                             f"{', '.join(EVAL_APPEARANCES)}")
        if self.frames < 1 or self.walk_steps < 1:
            raise ValueError("data.frames and data.walk_steps must be >= 1")
        for key in ("turn_prob", "keep_sparse_prob", "scanned_fraction", "min_object_fraction", "recolour_fraction"):
            if not 0 <= getattr(self, key) <= 1:   # also refuses NaN
                raise ValueError(f"data.{key} must be in [0, 1], got {getattr(self, key)}")
        w, h = self.resolution
        if not (16 <= w <= MAX_RESOLUTION_PX and 16 <= h <= MAX_RESOLUTION_PX):   # rendered like the sensor's
            raise ValueError(f"data.resolution must be between 16x16 and {MAX_RESOLUTION_PX}x{MAX_RESOLUTION_PX} "
                             f"pixels, got {w}x{h}")


# Ranges of the camera-like training levers (eval.segmenter.photometric): +-3 EV spans a dim room
# to a sunlit one; a log gain of 1 is ~2.7x between channels, beyond any white-balance error; an
# exponent factor of 2 ** 2 = 4 already crushes mid-tones; a vignette over 0.9 blacks the corners;
# a streak over 20 pixels smears a 160-pixel frame beyond recognition; 40 uint8 levels at white is
# a high-ISO phone sensor.
TRAIN_LEVER_RANGES = {
    "exposure_ev": Range(0, 3, "stops"),
    "white_balance": Range(0, 1),
    "tint": Range(0, 1),
    "gamma": Range(0, 2),
    "vignette": Range(0, 0.9),
    "motion_blur_prob": Range(0, 1),
    "motion_blur_px": Range(2, 20, "pixels"),
    "shot_noise": Range(0, 40, "uint8 levels"),
    "jpeg_prob": Range(0, 1),
}


@dataclass
class TrainConfig:
    """Optimisation and augmentation of a segmenter's training (``train``)."""

    net_stem: int = 16               # network: stride-2 stem channels
    net_stages: tuple[tuple[int, int], ...] = ((32, 2), (64, 3), (128, 4), (160, 2))  # network: (channels, blocks) at strides 4, 8, 16, 32
    net_decoder_width: int = 64      # network: FPN decoder channels
    net_depth_ratio: float = 1.0     # network (learned_rgbd): depth-branch width / RGB-branch width, (0, 2]; the
                                     # shipped weights: 1.0 (345,730 parameters; 0.5, before 2026-11-26: 229,338)
    init_weights: str = ""           # weight file the network starts from (fine-tuning, e.g. agent/weights/learned_rgb.pt:
                                     # same model, classes and train.net_* shape); "" = random initialisation
    epochs: int = 8                  # passes over the training frames
    batch_size: int = 16             # frames per step
    lr: float = 5e-3                 # peak learning rate (one-cycle schedule), AdamW
    weight_decay: float = 1e-4       # AdamW decoupled weight decay
    warmup_frac: float = 0.1         # fraction of steps spent warming up to the peak lr
    class_weighting: Literal["none", "inv_log"] = "inv_log"  # CE class weights: (1 / ln(1.02 + frequency)) ** power (ENet)
    class_weight_power: float = 0.5  # softens the ENet weights (1 = ENet: rare classes ~27x wall; 0.5: ~5x)
    val_frames: int = 200            # val-split frames scored after every epoch (0 = none)
    threads: int = 1                 # torch CPU threads; 0 = torch's default. 1: on a shared 2-core machine two
                                     # OpenMP threads stall at barriers whenever the other core is busy (measured
                                     # 10-100x slower steps); one thread is as fast as two with OMP_WAIT_POLICY=PASSIVE
    brightness: float = 0.3          # brightness gain drawn from 1 +- this
    contrast: float = 0.3            # contrast gain drawn from 1 +- this
    colour: float = 0.1              # per-channel gain drawn from 1 +- this
    rgb_noise_std: float = 4.0       # per-image Gaussian rgb noise std drawn from [0, this], uint8 levels
    depth_noise_std: float = 0.02    # per-image depth noise std drawn from [0, this], metres per metre
    hflip: bool = True               # mirror half of the batches' images left-right
    blur_prob: float = 0.25          # probability an image is Gaussian-blurred (scan-like soft colours), [0, 1]
    blur_sigma_px: float = 1.0       # blur std drawn from [0.3, this] per batch, pixels at the training resolution, [0.3, 5]
    depth_dropout_prob: float = 0.0  # probability an image's depth is blanked to 0 (invalid), [0, 1]: modality dropout,
                                     # so the RGB stream learns each class alone where a scan's geometry is damaged
    # camera-like levers (eval.segmenter.photometric), 0 = off (nothing drawn, the stream unchanged)
    exposure_ev: float = 0.0         # exposure gain 2 ** U(-this, this), EV stops, [0, 3]
    white_balance: float = 0.0       # blue-orange gains exp(+-t), t ~ U(-this, this) per image, log gain, [0, 1]
    tint: float = 0.0                # green-magenta gains exp(u) green, exp(-u/2) red / blue, u ~ U(-this, this), log gain, [0, 1]
    gamma: float = 0.0               # tone curve rgb ** 2 ** U(-this, this), log2 exponent, [0, 2]
    vignette: float = 0.0            # corner darkening 1 - s r ** 2, s ~ U(0, this) per image, [0, 0.9]
    motion_blur_prob: float = 0.0    # probability an image gets the batch's motion-blur streak, [0, 1]
    motion_blur_px: float = 6.0      # streak length drawn from [2, this] per batch, pixels at the training resolution, [2, 20]
    shot_noise: float = 0.0          # signal-dependent noise std at white drawn from [0, this] (std ~ sqrt(signal)), uint8 levels, [0, 40]
    jpeg_prob: float = 0.0           # probability an image is JPEG-compressed and decoded, [0, 1]
    jpeg_quality: tuple[int, int] = (30, 90)  # JPEG quality drawn uniformly from [lo, hi], cv2 quality, within [5, 100]

    def __post_init__(self) -> None:
        check_ranges(self, "train", TRAIN_LEVER_RANGES)
        lo, hi = self.jpeg_quality
        if isinstance(lo, bool) or isinstance(hi, bool) or not 5 <= lo <= hi <= 100:   # also refuses NaN
            raise ValueError(f"train.jpeg_quality must be [lo, hi] with 5 <= lo <= hi <= 100, got {list(self.jpeg_quality)}")
        if self.epochs < 1 or self.batch_size < 1:
            raise ValueError("train.epochs and train.batch_size must be >= 1")
        if not self.lr > 0:   # also refuses NaN
            raise ValueError(f"train.lr must be > 0, got {self.lr}")
        for key in ("blur_prob", "depth_dropout_prob"):
            if not 0 <= getattr(self, key) <= 1:   # also refuses NaN
                raise ValueError(f"train.{key} must be in [0, 1], got {getattr(self, key)}")
        if not 0 < self.net_depth_ratio <= 2:   # also refuses NaN
            raise ValueError(f"train.net_depth_ratio must be in (0, 2], got {self.net_depth_ratio}")
        if not 0.3 <= self.blur_sigma_px <= 5:
            raise ValueError(f"train.blur_sigma_px must be in [0.3, 5], got {self.blur_sigma_px}")


# ------------------------------------------------------------------ target-predictor training
# Keys of the predictor's training (``predictor_train``), and why their bounds: a pass over the
# collected maps takes minutes, so beyond 1000 passes a run never ends; goal cells are ~0.1-1 %
# of the cells a loss counts, so a weight of 1000 already over-weights them 1-10x (PEANUT's
# released script: 1, its weighted runs: inverse frequency); the held-out share must leave
# houses on both sides; a batch beyond 1024 maps (a collected set holds a few thousand) leaves
# too few steps per epoch for the one-cycle schedule; a peak rate above 1 diverges.
PREDICTOR_TRAIN_RANGES = {
    "epochs": Range(1, 1000, "epochs"),
    "pos_weight": Range(1, 1000),
    "val_fraction": Range(0, 1, lo_open=True, hi_open=True),
    "batch_size": Range(1, 1024, "maps"),
    "lr": Range(0, 1, lo_open=True),
}


@dataclass
class PredictorTrainConfig:
    """How ``calnav train-predictor`` trains the target predictor (``predictor_train``; the
    loss and held-out metrics: ``eval.prediction.train``)."""

    epochs: int = 12                 # passes over the training maps, epochs
    pos_weight: float = 20.0         # BCE weight of goal cells (the rest weigh 1), [1, 1000]
    seed: int = 0                    # seed of the held-out split, the initialisation and the batches
    val_fraction: float = 0.15       # share of the training houses held out when there is no --val-data, (0, 1)
    batch_size: int = 16             # maps per optimisation step
    lr: float = 1e-3                 # peak learning rate of the one-cycle schedule, Adam (PEANUT: 5e-4 on a
                                     # PSPNet-ResNet50 with batch 8)

    def __post_init__(self) -> None:
        check_ranges(self, "predictor_train", PREDICTOR_TRAIN_RANGES)
