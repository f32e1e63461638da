"""Typed settings of a house scan (``env.dataset.scanning``): the hand-held trajectory, the
RGB-D sensor model, and the reconstruction. Every key has a unit and a valid range; NaN and inf
are refused (every check is written so that a NaN fails it).

Defaults follow a Kinect-v1-class structured-light sensor (58 deg depth field of view, 0.4-4 m,
75 mm baseline, 1/8 px disparity steps at a 580 px focal length) and a ScanNet-like
reconstruction (2.5 cm TSDF, mesh decimated to ~2,100 triangles per m^2 of footprint, the density
of a ``_vh_clean_2`` apartment mesh: 153k triangles over 8 x 9 m).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

SCANNER_VERSION = 2   # 2: lived-in additions and floor artifacts; bump when a change to the scanner changes the scans (cache key)


def _check_range(owner: str, name: str, value: float, lo: float, hi: float,
                 lo_open: bool = False, hi_open: bool = False) -> None:
    """ValueError unless lo <(=) value <(=) hi (NaN and inf fail: every comparison is False)."""
    ok_lo = value > lo if lo_open else value >= lo
    ok_hi = value < hi if hi_open else value <= hi
    if not (isinstance(value, (int, float)) and math.isfinite(value) and ok_lo and ok_hi):
        interval = f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
        raise ValueError(f"{owner}.{name} must be in {interval}, got {value!r}")


@dataclass
class ScanningConfig:
    """How a procedural house is scanned and reconstructed (``env.dataset.style: scanned``)."""

    # --- trajectory: one tour of look-around stops spread over the free floor (envs.trajectories),
    # the camera held high and tilted down, then at some stops tilted up for one more turn
    stop_spacing_m: float = 1.5         # every free-floor point lies within this of a look-around stop, metres
    extra_turns_mean: float = 0.0       # extra full turns per stop beyond the first, Poisson mean, turns
    frames: int = 4000                  # most RGB-D frames per scan (the scan ends after one tour), frames
    camera_height_m: float = 1.3        # scanner height above the floor, metres
    pitch_deg: float = -25.0            # mean camera pitch, degrees (negative looks down)
    pitch_std_deg: float = 10.0         # slow pitch wander while scanning, degrees (std)
    up_turn_prob: float = 0.5           # chance that a stop ends with one more turn looking up (ceilings, upper walls; 0 = never: ceilings stay unscanned), probability
    up_pitch_deg: float = 30.0          # mean camera pitch of those turns, degrees (positive looks up)
    step_m: float = 0.15                # walking distance per frame, metres
    max_turn_deg: float = 30.0          # heading change per frame, degrees
    # --- depth sensor
    resolution: tuple[int, int] = (320, 240)  # scan frame size W x H, pixels
    hfov_deg: float = 58.0              # horizontal field of view of the scanner, degrees
    min_depth_m: float = 0.4            # closer returns are invalid, metres
    max_depth_m: float = 4.0            # maximum range: farther returns are invalid, metres
    axial_noise_m: float = 0.0012       # sigma_z = axial_noise_m + axial_noise_quad (z - axial_noise_z0_m)^2, metres
    axial_noise_quad: float = 0.0019    # quadratic growth of sigma_z, metres per square metre
    axial_noise_z0_m: float = 0.4       # depth where sigma_z is smallest, metres (Nguyen et al. 2012)
    baseline_m: float = 0.075           # projector-camera baseline of the disparity quantisation, metres
    disparity_focal_px: float = 580.0   # native focal length the disparity is measured at, pixels
    disparity_step_px: float = 0.125    # disparity quantisation step at that focal length, pixels (0 = off)
    lateral_jitter_px: float = 0.5      # per-pixel lateral shift of depth samples, pixels (std)
    grazing_max_deg: float = 78.0       # no return beyond this incidence angle, degrees (from the normal)
    dark_level: float = 25.0            # surfaces darker than this luminance absorb the pattern, uint8 levels
    bright_level: float = 250.0         # surfaces brighter than this saturate the sensor, uint8 levels
    absorb_dropout: float = 0.8         # chance a dark / saturated pixel has no return, probability
    edge_jump_m: float = 0.1            # a depth jump larger than this marks an occlusion edge, metres
    edge_width_px: int = 1              # pixels dropped on the far side of an occlusion edge, pixels
    random_dropout: float = 0.005       # chance any pixel has no return, probability
    # --- colour camera
    exposure_std_stops: float = 0.25    # per-frame exposure change, stops (std of log2 gain)
    white_balance_std: float = 0.05     # per-frame, per-channel colour gain change, fraction (std)
    blur_max_px: float = 2.0            # per-frame motion-blur length, uniform in [0, this], pixels
    rgb_noise_std: float = 2.0          # per-pixel colour noise, uint8 levels (std)
    # --- reconstruction (Open3D VoxelBlockGrid TSDF + marching cubes)
    voxel_m: float = 0.025              # TSDF voxel size, metres
    trunc_voxels: float = 4.0           # TSDF truncation, voxels
    min_weight: float = 2.0             # a voxel needs this many observations to hold surface, observations
    min_component_triangles: int = 100  # smaller disconnected pieces (floaters) are dropped after decimation, triangles (0 = keep)
    triangles_per_m2: float = 2100.0    # decimate to this many triangles per m^2 of footprint (0 = keep all), 1/m^2
    label_distance_m: float = 0.05      # a vertex farther than this from the clean mesh is void, metres
    # --- the lived-in house the scanner sees (envs.scanning.lived_in; all of it unlabelled)
    rug_prob: float = 0.5               # chance a room has a rug, probability
    rug_thickness_m: tuple[float, float] = (0.01, 0.03)       # rug thickness range, metres
    threshold_prob: float = 0.5         # chance a doorway has a threshold strip, probability
    threshold_height_m: tuple[float, float] = (0.015, 0.04)   # threshold height range, metres
    clutter_per_m2: float = 0.08        # small objects on the floor per m^2 of room, 1/m^2
    clutter_height_m: tuple[float, float] = (0.03, 0.3)       # their height range (up to 0.2 m the agent steps over them), metres
    # --- floor artifacts of the reconstruction (envs.scanning.artifacts)
    holes_per_m2: float = 0.06          # floor holes where the scanner never looked, per m^2 of room, 1/m^2
    hole_near_furniture: float = 0.7    # chance a hole sits beside a piece of furniture, probability
    hole_radius_m: tuple[float, float] = (0.08, 0.3)          # semi-axes of the elliptic holes, metres
    unlabelled_floor_fraction: float = 0.35  # floor area left void by the annotators, fraction
    floor_warp_m: float = 0.06          # most height of the floor's low-frequency warp (each house: 0.75-1 x this), metres
    floor_warp_wavelength_m: tuple[float, float] = (2.0, 6.0)  # wavelengths of the warp, metres

    def __post_init__(self) -> None:
        c = "scanning"
        self.resolution = tuple(int(v) for v in self.resolution)
        w, h = self.resolution
        if not (16 <= w <= 4096 and 16 <= h <= 4096):
            raise ValueError(f"{c}.resolution must be between 16x16 and 4096x4096 pixels, got {w}x{h}")
        for name, lo, hi, lo_open, hi_open in (
            ("stop_spacing_m", 0.3, 20.0, False, False),
            ("extra_turns_mean", 0.0, 10.0, False, False),
            ("frames", 1, 100_000, False, False),
            ("camera_height_m", 0.2, 2.5, False, False),
            ("pitch_deg", -80.0, 80.0, False, False),
            ("pitch_std_deg", 0.0, 45.0, False, False),
            ("up_turn_prob", 0.0, 1.0, False, False),
            ("up_pitch_deg", -80.0, 80.0, False, False),
            ("step_m", 0.0, 2.0, True, False),
            ("max_turn_deg", 0.0, 90.0, True, False),
            ("hfov_deg", 10.0, 150.0, False, False),
            ("min_depth_m", 0.0, 20.0, True, False),
            ("max_depth_m", 0.0, 50.0, True, False),
            ("axial_noise_m", 0.0, 0.5, False, False),
            ("axial_noise_quad", 0.0, 0.5, False, False),
            ("axial_noise_z0_m", 0.0, 20.0, False, False),
            ("baseline_m", 0.0, 1.0, True, False),
            ("disparity_focal_px", 0.0, 10_000.0, True, False),
            ("disparity_step_px", 0.0, 10.0, False, False),
            ("lateral_jitter_px", 0.0, 10.0, False, False),
            ("grazing_max_deg", 0.0, 90.0, True, False),
            ("dark_level", 0.0, 255.0, False, False),
            ("bright_level", 0.0, 256.0, False, False),
            ("absorb_dropout", 0.0, 1.0, False, False),
            ("edge_jump_m", 0.0, 10.0, True, False),
            ("edge_width_px", 0, 20, False, False),
            ("random_dropout", 0.0, 1.0, False, True),
            ("exposure_std_stops", 0.0, 3.0, False, False),
            ("white_balance_std", 0.0, 0.5, False, False),
            ("blur_max_px", 0.0, 30.0, False, False),
            ("rgb_noise_std", 0.0, 100.0, False, False),
            ("voxel_m", 0.005, 0.2, False, False),
            ("trunc_voxels", 1.0, 32.0, False, False),
            ("min_weight", 0.0, 1e6, False, False),
            ("min_component_triangles", 0, 10_000_000, False, False),
            ("triangles_per_m2", 0.0, 1e6, False, False),
            ("label_distance_m", 0.0, 1.0, True, False),
        ):
            _check_range(c, name, getattr(self, name), lo, hi, lo_open, hi_open)
        for name, lo, hi in (("rug_prob", 0.0, 1.0), ("threshold_prob", 0.0, 1.0), ("clutter_per_m2", 0.0, 10.0),
                             ("holes_per_m2", 0.0, 10.0), ("hole_near_furniture", 0.0, 1.0),
                             ("unlabelled_floor_fraction", 0.0, 1.0), ("floor_warp_m", 0.0, 0.5)):
            _check_range(c, name, getattr(self, name), lo, hi)
        for name, lo, hi in (("rug_thickness_m", 0.001, 0.2), ("threshold_height_m", 0.001, 0.2),
                             ("clutter_height_m", 0.005, 2.0), ("hole_radius_m", 0.01, 3.0),
                             ("floor_warp_wavelength_m", 0.1, 100.0)):
            pair = getattr(self, name)
            if not (isinstance(pair, (tuple, list)) and len(pair) == 2):
                raise ValueError(f"{c}.{name} must be a [low, high] pair, got {pair!r}")
            setattr(self, name, tuple(float(v) for v in pair))
            for v in getattr(self, name):
                _check_range(c, name, v, lo, hi)
            if not pair[0] <= pair[1]:
                raise ValueError(f"{c}.{name} must be [low, high] with low <= high, got {list(pair)}")
        if not self.min_depth_m < self.max_depth_m:
            raise ValueError(f"need {c}.min_depth_m < {c}.max_depth_m, got {self.min_depth_m}, {self.max_depth_m}")
        if not self.dark_level < self.bright_level:
            raise ValueError(f"need {c}.dark_level < {c}.bright_level, got {self.dark_level}, {self.bright_level}")

    def digest_items(self) -> dict:
        """Every setting as a plain dict (the cache key of a scanned house hashes it)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}
