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
- ``backends.parallel_efficiency``: the study's episodes (``bench.agent.STUDY``, ``val``
  EFFICIENCY_EPISODES) run twice as a user runs them, ``calnav objectnav`` in a subprocess:
  once with ``run.workers=1`` on one thread (``CALNAV_THREADS=1``, ``OMP_NUM_THREADS=1``: one
  core), once with ``run.workers=W`` on W cores (W = this machine's cores); efficiency =
  T1 / (W x TW), 1 = perfect scaling (target >= 0.9). Wall times of the whole commands
  (start-up included): ``backends.study_1_worker_s`` / ``backends.study_w_workers_s``.
- ``backends.concurrency_ceiling``: what the machine itself allows: W copies of the one-worker
  command started together (W independent processes, one thread each, no pool, no shared
  driver); ceiling = T1 / (the slowest copy's wall time), 1 = the cores do not slow each other
  down. Shared caches, memory bandwidth and a virtual machine's clock keep it below 1; the
  pool's efficiency cannot exceed it. ``backends.efficiency_vs_ceiling``: the ratio of the two
  (what the pool loses to its own start-up, feeding and driver).

The Ray figures are skipped when Ray is not installed; the efficiency is measured regardless.
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

EPISODES, QUICK_EPISODES = 20, 4
WORKERS = 2
EFFICIENCY_EPISODES, QUICK_EFFICIENCY_EPISODES = "100:140", "100:102"   # 40 episodes, ~4.5 min on 2 cores
OVERRIDES = ("env.resolution=160x120", "agent.segmenter=learned_rgb", "mapping.fusion=rbu")


def run(ctx) -> dict[str, float]:
    out = parallel_efficiency(ctx)
    try:
        import ray
    except ImportError:
        print("[bench] backends: ray is not installed (pip install -e \".[ray]\"); Ray figures skipped")
        return out
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
    return {**out, "backends.local_s": times["local"], "backends.ray_s": times["ray"],
            "backends.ray_vs_local": times["ray"] / times["local"],
            "backends.episodes_per_hour_local": 3600.0 * n / times["local"],
            "backends.episodes": float(n), "backends.workers": float(WORKERS)}


def parallel_efficiency(ctx) -> dict[str, float]:
    """``backends.parallel_efficiency`` and its two wall times (module docstring).

    The commands run as child processes, not as the runner's workers: what is timed is a whole
    ``calnav objectnav`` as a user starts it (interpreter start-up and imports included, the
    one-core environment set before them), and the ceiling is W independent processes with no
    pool and no shared driver. Each command's own workers are started by its runner."""
    import os
    import subprocess
    import sys

    from calnav.common.threads import ENV
    from calnav.eval.bench.agent import QUICK_STEPS, STUDY

    cores = os.cpu_count() or 1
    episodes = QUICK_EFFICIENCY_EPISODES if ctx.quick else EFFICIENCY_EPISODES
    extra = [f"env.max_episode_steps={QUICK_STEPS}"] if ctx.quick else []
    one_core = dict(os.environ) | {ENV: "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}

    def command(out: Path, workers: int) -> list[str]:
        return [sys.executable, "-m", "calnav", "objectnav", "--episodes", episodes, "--output", str(out),
                *STUDY, *extra, f"run.workers={workers}"]

    def timed(runs: list[tuple[list[str], dict]]) -> float:
        """Wall seconds until the last of ``runs`` (started together) has finished."""
        t0 = time.perf_counter()
        procs = [subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                 for cmd, env in runs]
        try:
            codes = [p.wait() for p in procs]
        finally:
            for p in procs:   # a failed or interrupted measurement leaves no process behind
                if p.poll() is None:
                    p.kill()
        if any(codes):
            raise RuntimeError(f"bench backends: a calnav objectnav run failed (exit codes {codes})")
        return time.perf_counter() - t0

    with tempfile.TemporaryDirectory(prefix="calnav-bench-efficiency-") as tmp:
        t1 = timed([(command(Path(tmp) / "w1", 1), one_core)])   # one worker on one core: the baseline
        tw = timed([(command(Path(tmp) / f"w{cores}", cores), dict(os.environ))])
        together = timed([(command(Path(tmp) / f"copy{i}", 1), one_core) for i in range(cores)])
    efficiency, ceiling = t1 / (cores * tw), t1 / together
    return {"backends.parallel_efficiency": efficiency, "backends.concurrency_ceiling": ceiling,
            "backends.efficiency_vs_ceiling": efficiency / ceiling,
            "backends.study_1_worker_s": t1, "backends.study_w_workers_s": tw,
            "backends.study_copies_s": together, "backends.efficiency_workers": float(cores)}
