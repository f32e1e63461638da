"""Memory a semantic voxel map of a config takes (``mapping.voxel_map.SemanticVoxelMap``), for
the preflight's estimate (``eval.memory``): what the map allocates up front, and the dense block
table one frame's integration builds."""
from __future__ import annotations

import numpy as np

from calnav.mapping.config import MappingConfig
from calnav.mapping.fusion import get_strategy
from calnav.mapping.voxel_map import BASE_ATTRS, MIB, MIN_BLOCKS

# A frame's dense block table (``frame_geometry.BlockTable``) spans its touched blocks plus one
# block of padding on each side: up to ceil(extent / block) + 3 cells per axis. Per cell it holds
# the frame's flag and a scratch mark (bool each) and a buffer index (int64); per voxel of its
# cells the candidates' stamp (int32, ``SemanticVoxelMap._candidates``).
TABLE_PAD_BLOCKS = 3
TABLE_CELL_BYTES = 1 + 1 + 8
TABLE_VOXEL_BYTES = 4


def voxel_map_bytes(num_classes: int, cfg: MappingConfig, tsdf: bool = True,
                    frame_extent_m: tuple[float, float, float] | None = None) -> int:
    """Bytes a map of ``cfg`` takes before it grows: Open3D's hashmap as allocated up front
    (``block_count`` blocks, or ``initial_alloc_mb``'s worth, at least MIN_BLOCKS; it doubles on
    demand as the mapped volume grows, which no config bounds) plus, when ``frame_extent_m``
    (x, y, z) gives the axis-aligned extent in metres that a frame's points can span, that
    frame's dense block table (TABLE_* above), whose blocks reach the association or truncation
    band beyond the surface."""
    channels = (sum(c for _, c in BASE_ATTRS) if tsdf else 0) + \
        sum(get_strategy(cfg.fusion).channels(num_classes).values()) + 1   # + the observation count
    res = cfg.block_resolution
    bytes_per_block = res ** 3 * channels * np.dtype(np.float32).itemsize
    blocks = cfg.block_count or max(MIN_BLOCKS, int(cfg.initial_alloc_mb * MIB / bytes_per_block))
    total = blocks * bytes_per_block
    if frame_extent_m is not None:
        block_m = cfg.voxel_size_m * res
        band_m = max(cfg.trunc_voxels, cfg.association_band_voxels) * cfg.voxel_size_m
        cells = np.prod([np.ceil((extent + 2 * band_m) / block_m) + TABLE_PAD_BLOCKS for extent in frame_extent_m])
        total += cells * (TABLE_CELL_BYTES + res ** 3 * TABLE_VOXEL_BYTES)
    return int(total)
