"""Scanned houses: every procedural house as a simulated scan of itself (``env.dataset.style:
scanned``). ``config`` (settings), ``sensor`` (RGB-D sensor model), ``reconstruct`` (TSDF,
meshing, label transfer), ``scanner`` (the scan loop), ``quality`` (how scan-like a result is).
Kept import-free so ``envs.config`` can read the settings without loading Open3D."""
