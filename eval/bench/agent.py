"""Bench section "agent": speed and memory of the PEANUT-like agent's loop.

One ``val`` episode (index EPISODE) of the gym env at 160x120 with the ``gt`` segmenter and
the default fused map; the agent runs in explore-only mode (goal_threshold 1.0, above what the
default averaging fusion of the 0.9-confidence gt segmenter can reach), so it maps for the
whole step limit, the worst case for time and memory:

- ``agent.hz_160x120``: steps per second of the full loop (env step = move + render, then
  segment + fuse + project + plan in ``act``), wall time over the episode (target >= 15).
- ``agent.act_ms_160x120``: median ``act`` time, ms.
- ``agent.rss_growth_mb_500_steps``: resident memory after the last step minus after the first,
  MiB (target < 300).
- ``agent.ms_per_step_learned_rgb_160x120``: wall time per step of the study's agent
  (``STUDY``: ``learned_rgb`` + GLFS with the shipped parameters, the tuned threshold, 160x120)
  over whole ``val`` episodes (``STUDY_EPISODES``), env step included, in a worker process pinned
  to one thread (``common.threads``) -- one core, as each worker of a study has (target <= 10).
  The worker runs the episodes twice and the second pass is measured: a study's worker runs
  hundreds of episodes, and its one-time costs -- compiling / loading kernels, the voxel
  map's hashmap doubling once or twice to the largest house's size (~0.9 s each on the
  bench machine; the agent keeps its allocation between episodes) -- are spread over all of
  them. ``agent.ms_per_step_first_pass`` is the first pass, one-time costs included.
- ``objectnav.episodes_per_core_hour``: the measured pass as episodes per hour of that one core.
- ``agent.rerun_overhead``: recording an episode to Rerun (``--rerun``, ``agent.recording``, its
  defaults) as a fraction of the episode's wall time, the study agent on ``RERUN_EPISODES``
  (each run plain and recorded, in this process, after a warm-up; target <= 0.2);
  ``agent.rerun_mb_per_episode``: the mean ``.rrd`` size, MB (target <= ~50), and
  ``agent.rerun_kb_per_step``. Skipped without the ``[viz]`` extra.
- ``agent.prediction.hz_160x120`` / ``act_ms_160x120``: the same episode with
  ``agent.exploration=prediction`` (the shipped ``agent/weights/predictor.pt``; skipped without
  it); ``agent.prediction.call_ms``: median time of one target prediction (input window +
  network), called when the long-term goal is re-chosen (every ``agent.replan_steps``).
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from calnav.eval.rollout import Hook, rollout

EPISODE = 0
STEPS = 500
# the ObjectNav study's settings (docs/objectnav_study.md): what episodes per core-hour is about
STUDY = ("env.resolution=160x120", "agent.segmenter=learned_rgb", "mapping.fusion=glfs",
         "mapping.glfs_params=agent/weights/glfs_learned_rgb.json", "agent.goal_threshold=0.5",
         "agent.goal_min_area_cells=4")
STUDY_EPISODES = range(101, 113)   # 12 episodes, each run twice (the first pass warms up): ~60 s
QUICK_STUDY_EPISODES = range(101, 102)
RERUN_EPISODES, QUICK_RERUN_EPISODES = (100, 101, 102), (100,)
QUICK_STEPS = 60
STUDY_WORKER_THREADS = 1   # one core: what each worker of a study with run.workers = the cores has
EXPLORE_ONLY_THRESHOLD = 1.0
MIB = float(1 << 20)


class TimedAct:
    """An agent whose ``act`` calls are timed (``act_ms``, ms each)."""

    def __init__(self, agent):
        self.agent, self.act_ms = agent, []

    def reset(self, obs: dict) -> None:
        self.agent.reset(obs)

    def act(self, obs: dict):
        t = time.perf_counter()
        step = self.agent.act(obs)
        self.act_ms.append((time.perf_counter() - t) * 1e3)
        return step


class LoopTimer(Hook):
    """The loop's wall seconds from the agent's reset to the last step (``wall_s``) and the
    resident memory after the first ``act`` (``rss0``, MiB: what the loop grows from)."""

    def on_reset(self, env, agent, obs, info) -> None:
        self.t0, self.rss0, self.wall_s = time.perf_counter(), None, 0.0

    def before_step(self, env, step, obs, action: int) -> int:
        if self.rss0 is None:
            self.rss0 = rss_mb()
        return action

    def on_end(self, env, agent, result) -> None:
        self.wall_s = time.perf_counter() - self.t0


def val_env(env_cfg, upto: int):
    """The gym env over the ``val`` episodes ``0:upto`` only (``envs.episodes.load_split``'s
    prefix: the same indices as the whole split's), so a fresh cache generates the houses those
    episodes lie in, not every house of the split."""
    import gymnasium as gym

    import calnav.envs  # noqa: F401  (registers the env)
    from calnav.envs.episodes import load_split

    return gym.make("calnav/ObjectNav-v0", split="val", config=env_cfg, episodes=load_split("val", env_cfg, upto=upto))


def rss_mb() -> float:
    """Resident set size of this process, MiB (Linux /proc)."""
    import os

    with open("/proc/self/statm") as f:
        pages = int(f.read().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / MIB


def run(ctx) -> dict[str, float]:
    from calnav.agent.prediction import DEFAULT_PREDICTOR

    hz, act_ms, rss_growth, n = agent_loop(ctx)
    out = {"agent.hz_160x120": hz, "agent.act_ms_160x120": act_ms,
           "agent.rss_growth_mb_500_steps": rss_growth, "agent.bench_steps": float(n), **study_figures(ctx),
           **rerun_figures(ctx)}
    if not DEFAULT_PREDICTOR.is_file():
        print(f"[bench] agent: skipping the prediction figures: no {DEFAULT_PREDICTOR}", flush=True)
        return out
    calls: list[float] = []
    hz, act_ms, _, _ = agent_loop(ctx, ("agent.exploration=prediction",), predictor_calls=calls)
    out.update({"agent.prediction.hz_160x120": hz, "agent.prediction.act_ms_160x120": act_ms,
                "agent.prediction.call_ms": float(np.median(calls)) if calls else float("nan"),
                "agent.prediction.calls": float(len(calls))})
    return out


def agent_loop(ctx, overrides: tuple[str, ...] = (), predictor_calls: list[float] | None = None
               ) -> tuple[float, float, float, int]:
    """(steps per second, median act ms, RSS growth MiB, steps) of the explore-only episode of
    the module docstring; ``overrides`` change the config (e.g. env.dataset.style=scanned).
    ``predictor_calls``: filled with the ms of each target-prediction call (exploration:
    prediction), the network and its input."""
    from calnav.agent.policy import PeanutAgent
    from calnav.eval.config import agent_setup, load_config

    cfg = load_config(None, ["env.resolution=160x120", "agent.segmenter=gt", *overrides])
    cfg.agent = dataclasses.replace(cfg.agent, goal_threshold=EXPLORE_ONLY_THRESHOLD)
    steps = QUICK_STEPS if ctx.quick else STEPS
    cfg.env = dataclasses.replace(cfg.env, max_episode_steps=steps)
    env = val_env(cfg.env, EPISODE + 1)
    agent = PeanutAgent(agent_setup(cfg, "peanut"))
    if predictor_calls is not None and agent.predictor is not None:
        network = agent.predictor.probabilities   # its own name: ``timed`` below is the timed agent

        def probabilities(*args, **kwargs):
            t = time.perf_counter()
            result = network(*args, **kwargs)
            predictor_calls.append((time.perf_counter() - t) * 1e3)
            return result
        agent.predictor.probabilities = probabilities
    timed, loop = TimedAct(agent), LoopTimer()
    rollout(env, timed, EPISODE, [loop], max_steps=steps)
    n = len(timed.act_ms)
    return n / loop.wall_s, float(np.median(timed.act_ms)), rss_mb() - loop.rss0, n


@dataclass(frozen=True)
class StudyPasses:
    """The runner's task for ``study_figures``: ``val`` episodes ``indices`` in this order (the
    first pass, then the measured one), each capped at ``steps_cap`` steps when > 0."""

    indices: tuple[int, ...]
    steps_cap: int = 0


def run_study_passes(task: StudyPasses) -> tuple[list[int], list[float]]:
    """The worker's side of ``study_figures``: ``study_episodes`` of ``task``."""
    return study_episodes(list(task.indices), task.steps_cap)


def study_figures(ctx) -> dict[str, float]:
    """``agent.ms_per_step_*`` and ``objectnav.episodes_per_core_hour`` (module docstring),
    measured through the runner in one fresh spawned worker pinned to one thread, as each
    worker of a study using all cores is (this process has loaded and threaded the libraries
    for the other sections: it would time something else)."""
    from calnav.eval.backends import LocalBackend
    from calnav.eval.runner import run_tasks

    indices = list(QUICK_STUDY_EPISODES if ctx.quick else STUDY_EPISODES)
    task = StudyPasses(tuple(indices * 2), QUICK_STEPS if ctx.quick else 0)
    results: dict[StudyPasses, tuple[list[int], list[float]]] = {}
    failures = run_tasks(run_study_passes, [task], None, save=results.__setitem__, desc="bench agent", unit="run",
                         progress=False, backend=LocalBackend(1, threads=STUDY_WORKER_THREADS, in_process=False))
    if failures:
        failed = failures[0][1]
        raise RuntimeError(f"bench agent: the study worker failed: {failed.error}\n{failed.traceback}")
    steps, walls = results[task]
    first = 1e3 * sum(walls[:len(indices)]) / sum(steps[:len(indices)])
    steps, walls = steps[len(indices):], walls[len(indices):]   # the second pass is measured
    return {"agent.ms_per_step_learned_rgb_160x120": 1e3 * sum(walls) / sum(steps),
            "agent.ms_per_step_first_pass": first,
            "objectnav.episodes_per_core_hour": 3600.0 * len(walls) / sum(walls),
            "objectnav.bench_episodes": float(len(walls))}


def study_episodes(indices: list[int], steps_cap: int = 0) -> tuple[list[int], list[float]]:
    """Run the study agent (``STUDY``) over ``val`` episodes ``indices`` in this process; returns
    the steps and the wall seconds (reset + every agent and env step) of each. ``steps_cap`` > 0
    shortens the episodes (quick runs)."""
    from calnav.agent.policy import PeanutAgent
    from calnav.eval.config import agent_setup, load_config

    cfg = load_config(None, [*STUDY, *([f"env.max_episode_steps={steps_cap}"] if steps_cap else [])])
    env = val_env(cfg.env, max(indices) + 1)
    agent = PeanutAgent(agent_setup(cfg, "peanut"))
    steps, walls = [], []
    for index in indices:
        t0 = time.perf_counter()
        steps.append(rollout(env, agent, index).steps)
        walls.append(time.perf_counter() - t0)
    env.close()
    return steps, walls


def rerun_figures(ctx) -> dict[str, float]:
    """``agent.rerun_*`` (module docstring)."""
    import importlib.util
    import tempfile
    from pathlib import Path

    if importlib.util.find_spec("rerun") is None:
        print('[bench] agent: rerun-sdk is not installed (pip install -e ".[viz]"); Rerun figures skipped', flush=True)
        return {}
    import rerun  # noqa: F401  (imported once per worker process, not per episode: not timed)

    from calnav.agent.policy import PeanutAgent
    from calnav.eval.config import agent_setup, load_config
    from calnav.eval.objectnav.run import run_one_episode

    cap = [f"env.max_episode_steps={QUICK_STEPS}"] if ctx.quick else []
    cfg = load_config(None, [*STUDY, *cap])
    episodes = QUICK_RERUN_EPISODES if ctx.quick else RERUN_EPISODES
    env = val_env(cfg.env, max(episodes) + 1)
    agent = PeanutAgent(agent_setup(cfg, "peanut"))
    run_one_episode(env, agent, episodes[0])   # warm-up: the voxel map's allocation grows once
    plain = recorded = 0.0
    sizes, steps = [], 0
    with tempfile.TemporaryDirectory(prefix="calnav-bench-rerun-") as tmp:
        for index in episodes:
            t = time.perf_counter()
            rec = run_one_episode(env, agent, index)
            plain += time.perf_counter() - t
            t = time.perf_counter()
            rec = run_one_episode(env, agent, index, rerun_dir=Path(tmp))
            recorded += time.perf_counter() - t
            sizes.append(Path(rec["rerun"]).stat().st_size / 1e6)
            steps += rec["steps"]
    env.close()
    return {"agent.rerun_overhead": recorded / plain - 1.0, "agent.rerun_mb_per_episode": float(np.mean(sizes)),
            "agent.rerun_kb_per_step": 1e3 * sum(sizes) / steps}
