"""Bench section "backends": the overhead of running ObjectNav episodes as Ray tasks instead of
in the local process pool, on this machine with the same number of workers.

- ``backends.local_s`` / ``backends.ray_s``: wall time of the same episodes (the PEANUT-like
  agent, ``learned_rgb`` + RBU, 160x120, ``val`` episodes 0:N) through
  ``eval.objectnav.run.run_jobs`` with ``run.backend=local`` and ``run.backend=ray``, each into
  a fresh directory, seconds. The Ray figure includes starting the local Ray instance, as a
  user's first run pays it.
- ``backends.ray_vs_local``: ray_s / local_s (target <= 1.15).
- ``backends.episodes_per_hour_local``: episodes per hour on this machine (local pool).
- ``backends.episodes`` / ``backends.workers``: what was measured.

Skipped (no figures) when Ray is not installed.
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

EPISODES, QUICK_EPISODES = 20, 4
WORKERS = 2
OVERRIDES = ("env.resolution=160x120", "agent.segmenter=learned_rgb", "mapping.fusion=rbu")


def run(ctx) -> dict[str, float]:
    try:
        import ray
    except ImportError:
        print("[bench] backends: ray is not installed (pip install -e \".[ray]\"); skipped")
        return {}
    from calnav.eval.config import load_config
    from calnav.eval.objectnav.run import EpisodeJob, run_jobs

    n = QUICK_EPISODES if ctx.quick else EPISODES
    times = {}
    with tempfile.TemporaryDirectory(prefix="calnav-bench-backends-") as tmp:
        for backend in ("local", "ray"):
            cfg = load_config(None, [*OVERRIDES, f"run.workers={WORKERS}", f"run.backend={backend}"])
            t0 = time.perf_counter()
            run_jobs([EpisodeJob(cfg, list(range(n)), Path(tmp) / backend)], progress=False, plots=False)
            times[backend] = time.perf_counter() - t0
    if ray.is_initialized():
        ray.shutdown()
    return {"backends.local_s": times["local"], "backends.ray_s": times["ray"],
            "backends.ray_vs_local": times["ray"] / times["local"],
            "backends.episodes_per_hour_local": 3600.0 * n / times["local"],
            "backends.episodes": float(n), "backends.workers": float(WORKERS)}
