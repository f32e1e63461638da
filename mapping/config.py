"""Typed configuration of the semantic voxel map and its fusion (see ``mapping.fusion``)."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass
class MappingConfig:
    fusion: str = "averaging"        # fusion strategy: rbu | averaging | histogram | geometric_mean | glfs
    voxel_size_m: float = 0.05       # voxel edge length, metres
    block_resolution: int = 8        # voxels per block edge (Open3D VoxelBlockGrid)
    block_count: int = 20000         # initial hashmap capacity, blocks (grows on demand)
    trunc_voxels: float = 4.0        # TSDF truncation, in voxels
    depth_max_m: float = 5.0         # depth beyond this is not integrated, metres
