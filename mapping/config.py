"""Typed configuration of the semantic voxel map and its fusion (see ``mapping.fusion``).

Memory sizing (``block_count`` / ``initial_alloc_mb``): Open3D allocates the voxel-block
hashmap up front, ``block_count * res^3 * channels * 4 B``. The channels are tsdf (1), weight
(1), colour (3), observation count (1) plus the fusion strategy's accumulators (``rbu``: K;
``averaging``/``histogram``/``geometric_mean``: K + 1; ``glfs``: 2K + 1). With K = 18 and
res = 8 a block (0.4 m cube at 5 cm voxels) costs 49 KB (rbu) to 88 KB (glfs), so the default
192 MiB budget starts with ~4000 (rbu) to ~2200 (glfs) blocks. Measured on a procedural house
(``calnav bench``, ``fusion.mb_per_m2``): ~4.1 MiB per m^2 of mapped floor for glfs, ~2.3 for
rbu, so the initial allocation holds ~45-80 m^2 of house. The hashmap doubles itself when full
(one ~0.3 s pause), so memory follows the observed volume instead of being sized for the
largest house. block_resolution = 4 measured ~40 % less memory per m^2 at the same speed.
"""
from __future__ import annotations

from dataclasses import dataclass

from calnav.common.ranges import Range, check_ranges
from calnav.mapping.registry import FUSIONS, check_weighting

# Laplace smoothing constant mu: p' = (p + mu) / (1 + K mu) before any log (paper Sec. III-B and
# V-A smooth before the log-space updates but give no value; 1e-3 is the authors' constant).
# The one definition: ``mapping.fusion`` imports it from here.
LAPLACE_MU = 1e-3
# Largest image side the map takes, pixels (``envs.config.MAX_RESOLUTION_PX``, the sensor's).
MAX_IMAGE_SIDE_PX = 4096
# The GLFS sample-weight table's bins (``mapping.weighting``'s ``lut``): the authors' distance
# edges, metres, and incidence-angle edges, degrees. Here, not in ``mapping.weighting`` (torch),
# so the GLFS training section (``mapping.calibration.glfs_config``) loads without torch.
DISTANCE_EDGES_M: tuple[float, ...] = (0.0, 1.0, 2.0, 3.0, 4.0, 5.0)
ANGLE_EDGES_DEG: tuple[float, ...] = (0.0, 30.0, 60.0, 90.0)


MAX_ALLOC_MB = 65536          # initial_alloc_mb cap, MiB (64 GiB: beyond any machine this runs on)
MAX_BLOCK_COUNT = 50_000_000  # block_count cap, blocks
METRES = "metres"
VOXELS = "voxels"

# Size-like keys of the map (``mapping``), and why their bounds:
MAPPING_RANGES = {
    # a voxel of 5 mm to 0.5 m: finer than a depth sensor's noise (Kinect-class: 1-4 mm at 1 m)
    # gains nothing while each frame's dense block table grows as 1 / voxel^3 (checked against
    # memory by the preflight); coarser than 0.5 m, a chair or a toilet is one voxel or none
    "voxel_size_m": Range(0.005, 0.5, METRES),
    # Open3D blocks of 2^3 to 32^3 voxels: one 32^3 block of K = 18 GLFS channels is already 5 MiB
    "block_resolution": Range(2, 32, VOXELS),
    # the TSDF band: at least one voxel (else no zero crossing is stored), at most 32 (the band
    # then spans rooms: every surface bleeds into the next)
    "trunc_voxels": Range(1.0, 32.0, VOXELS),
    # depth range: within 100 m, beyond any indoor sensor (the frame table covers it)
    "depth_min_m": Range(0.0, 100.0, METRES),
    "depth_max_m": Range(0.0, 100.0, METRES, lo_open=True),
    # weighting distances: within a 100 m view, above 0 where they divide
    "distance_ref_m": Range(0.0, 100.0, METRES, lo_open=True),
    "sweet_spot_m": Range(0.0, 100.0, METRES),
    "sweet_spot_halfwidth_m": Range(0.0, 100.0, METRES, lo_open=True),
    # association in voxels: above 0 (a zero band matches nothing), within 64 (more spans rooms)
    "sample_spacing_voxels": Range(0.0, 64.0, VOXELS, lo_open=True),
    "association_band_voxels": Range(0.0, 64.0, VOXELS, lo_open=True),
    "surface_band_voxels": Range(0.0, 64.0, VOXELS, lo_open=True),
    # pixel strides within the largest sensor (0 = auto)
    "pixel_stride": Range(0, MAX_IMAGE_SIDE_PX, "pixels"),
    "normal_offset_px": Range(0, MAX_IMAGE_SIDE_PX, "pixels"),
}


@dataclass
class MappingConfig:
    # --- fusion -----------------------------------------------------------------------------
    fusion: str = "averaging"        # fusion strategy (mapping.registry.FUSIONS): rbu | averaging | histogram | geometric_mean | glfs
    weighting: str = "auto"          # sample weighting (mapping.registry.WEIGHTINGS): auto (glfs: lut, else none) | none | lut | distance | incidence | sweet_spot
    temperature: float = 1.0         # logit temperature for non-glfs strategies (glfs: tau from glfs_params)
    glfs_params: str = ""            # GLFSParams file (.json/.npz) for glfs / lut; "" = identity (tau 1, G = eps = 0, M = 1)
    laplace_mu: float = LAPLACE_MU   # Laplace smoothing p' = (p + mu) / (1 + K mu) before any log
    # --- sample-weighting heuristics (paper Sec. V-B; see mapping.weighting) -----------------
    distance_ref_m: float = 1.0      # 'distance': weight 1 up to this range, then (ref / d)^2, metres
    sweet_spot_m: float = 1.5        # 'sweet_spot': best segmentation distance, metres
    sweet_spot_halfwidth_m: float = 3.0  # 'sweet_spot': weight falls to min_sample_weight this far away, metres
    min_sample_weight: float = 0.05  # floor of the analytic weights (an observation never counts for nothing)
    # --- geometry ---------------------------------------------------------------------------
    voxel_size_m: float = 0.05       # voxel edge length, metres
    block_resolution: int = 8        # voxels per block edge (Open3D VoxelBlockGrid)
    block_count: int = 0             # initial hashmap capacity, blocks (grows on demand); 0 = from initial_alloc_mb
    initial_alloc_mb: float = 192.0  # initial allocation when block_count = 0, MiB
    trunc_voxels: float = 4.0        # TSDF truncation, in voxels
    depth_min_m: float = 0.1         # depth below this is invalid, metres
    depth_max_m: float = 5.0         # depth beyond this is not integrated, metres
    # --- semantic association ---------------------------------------------------------------
    pixel_stride: int = 0            # candidate-pixel stride; 0 = auto (see sample_spacing_voxels)
    sample_spacing_voxels: float = 1.0  # auto stride: candidate spacing at depth_max, in voxels
    association_band_voxels: float = 4.0  # |voxel z - depth at its pixel| limit (rejects occlusion edges), voxels
    normal_offset_px: int = 0        # depth-image normal baseline, pixels; 0 = auto (width / 160)
    # --- read-out ---------------------------------------------------------------------------
    surface_band_voxels: float = 2.0  # read-out keeps voxels with |sdf| below this many voxels
    min_tsdf_weight: float = 1.0     # read-out / ray casting: minimum TSDF weight (frames)

    def __post_init__(self) -> None:
        FUSIONS.check(self.fusion)
        check_weighting(self.weighting)
        for name in ("temperature", "initial_alloc_mb"):
            if not getattr(self, name) > 0:
                raise ValueError(f"mapping.{name} must be > 0, got {getattr(self, name)}")
        check_ranges(self, "mapping", MAPPING_RANGES)
        if not 0 <= self.depth_min_m < self.depth_max_m:
            raise ValueError(f"need 0 <= mapping.depth_min_m < mapping.depth_max_m, got {self.depth_min_m}, {self.depth_max_m}")
        if self.initial_alloc_mb > MAX_ALLOC_MB:   # a typo such as 1e12 fails here, not as an allocation failure
            raise ValueError(f"mapping.initial_alloc_mb must be in (0, {MAX_ALLOC_MB}] MiB, got {self.initial_alloc_mb:g}")
        if self.block_count > MAX_BLOCK_COUNT:
            raise ValueError(f"mapping.block_count must be in [0, {MAX_BLOCK_COUNT}] blocks, got {self.block_count}")
        res = self.block_resolution
        if res & (res - 1):
            raise ValueError(f"mapping.block_resolution must be a power of two in [2, 32], got {res}")
        if self.block_count < 0:
            raise ValueError(f"mapping.block_count must be >= 0, got {self.block_count}")
        if not 0 < self.laplace_mu < 1:
            raise ValueError(f"mapping.laplace_mu must be in (0, 1), got {self.laplace_mu}")
        if not 0 < self.min_sample_weight <= 1:
            raise ValueError(f"mapping.min_sample_weight must be in (0, 1], got {self.min_sample_weight}")
        if not self.min_tsdf_weight >= 0:
            raise ValueError(f"mapping.min_tsdf_weight must be >= 0, got {self.min_tsdf_weight}")
