"""Calibrated semantic 3D mapping (paper Sec. III-V).

- ``mapping.fusion``: fusion strategies (rbu, averaging, histogram, geometric_mean, glfs) as
  accumulator increments + read-outs, and the batched differentiable ``fuse``.
- ``mapping.scaling`` / ``mapping.weighting`` / ``mapping.glfs``: logit temperature / vector
  scaling, sample weighting (GLFS look-up table and analytic heuristics), GLFS parameters.
- ``mapping.voxel_map``: ``SemanticVoxelMap``, the incremental TSDF + semantic voxel map.
- ``mapping.calibration.obs_cache``: per-voxel observation cache for offline calibration / GLFS training.
- ``mapping.ground_truth``: voxel and pixel ground truth from a labelled mesh.

``mapping`` imports neither ``envs`` nor ``agent`` nor ``eval``; heavy modules (torch, Open3D)
load only when a submodule is imported.
"""
