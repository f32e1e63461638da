"""Offline calibration of the fused map (paper Sec. IV-V): ``obs_cache`` (per-voxel
observations recorded while mapping), ``flat_obs`` (the same, flattened for fast re-fusion),
``fit`` (2D / 3D temperature and 3D vector scaling), ``glfs_train`` (learning GLFS) and
``metrics_torch`` (differentiable ECE / mECE). The online map (``mapping.voxel_map``,
``mapping.fusion``) never imports this package."""
