"""Scanned houses: every procedural house as a simulated scan of itself (``env.dataset.style:
scanned``). ``config`` (settings), ``lived_in`` (the house as the scanner finds it: rugs,
thresholds, clutter), ``sensor`` (RGB-D sensor model), ``reconstruct`` (TSDF, meshing, label
transfer), ``artifacts`` (floor holes, unlabelled floor, warp), ``scanner`` (the scan loop),
``quality`` (how scan-like a result is).
Kept import-free so ``envs.config`` can read the settings without loading Open3D."""
