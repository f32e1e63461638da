"""``calnav collect-maps``: training data for the target predictor (``agent.prediction``).

The PEANUT-like agent explores the houses of ``--split`` (``train``; ``val`` for held-out maps) with the config's segmenter, map type and
fusion (exploration only, as PEANUT collects: a STOP becomes a turn, so each episode runs its
``--steps``), and every ``--every`` steps the predictor's input around the agent is saved with
the target: for each goal category, the coarse cells its instances occupy in the *whole* house
(the house's ground-truth mesh, rasterised top-down in the episode's start frame -- the agent
never sees it). One file per episode, ``episodes/<index>.npz`` (``inputs`` (T, C, S, S) uint8 =
value x 255, ``targets`` (T, G, S, S) uint8 0/1, ``steps`` (T,)), written atomically as it
arrives from a worker: an interrupted run resumes where it stopped.

    calnav collect-maps --episodes 0:200 --output runs/maps_glfs agent.segmenter=learned_rgb \\
        mapping.fusion=glfs mapping.glfs_params=agent/weights/glfs_learned_rgb.json
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calnav.eval.config import Config
from calnav.eval.results_dir import ResultsDir
from calnav.eval.rollout import Hook
from typing import Literal
from calnav.eval.arguments import REQUIRED, Command, arg

MAPS_FORMAT = 1


@dataclass
class CollectTask:
    cfg: Config   # the run's config, validated where it was loaded: it pickles to the worker as it is
    index: int
    steps: int
    every: int
    upto: int | None = None   # the run's episodes lie in 0:upto (a worker loads those scenes only)


def episode_file(out: Path, index: int) -> Path:
    return Path(out) / "episodes" / f"{index:05d}.npz"


def goal_targets(scene, episode, state_origin: np.ndarray, corner: tuple[int, int], spec, map_cell_m: float,
                 goals: tuple[str, ...]) -> np.ndarray:
    """(G, S, S) uint8: 1 where an instance of goal ``goals[g]`` lies in the coarse cell, the
    mesh rasterised top-down in the episode's start frame (x forward, y left: the agent's
    map frame), on the predictor window whose corner is map cell ``corner`` (row, col)."""
    import cv2

    from calnav.agent.prediction import pool_factor

    f = pool_factor(spec, map_cell_m)
    s = spec.window_cells
    c, sn = np.cos(-episode.start_yaw), np.sin(-episode.start_yaw)
    out = np.zeros((len(goals), s, s), np.uint8)
    for g, name in enumerate(goals):
        if name not in scene.class_names:
            continue
        tris = scene.triangles[scene.tri_class == scene.class_names.index(name)]
        if len(tris) == 0:
            continue
        xy = scene.vertices[tris][..., :2].astype(np.float64) - episode.start_position[:2]
        local = np.stack([c * xy[..., 0] - sn * xy[..., 1], sn * xy[..., 0] + c * xy[..., 1]], -1)
        # coarse-cell coordinates with cell j spanning [j, j + 1); OpenCV's pixel j spans [j - 0.5, j + 0.5]
        cols = ((local[..., 0] - state_origin[0]) / map_cell_m - corner[1]) / f - 0.5
        rows = ((local[..., 1] - state_origin[1]) / map_cell_m - corner[0]) / f - 0.5
        pts = np.round(np.stack([cols, rows], -1) * 16).astype(np.int32)   # 4 fractional bits
        cv2.fillPoly(out[g], list(pts), 1, lineType=cv2.LINE_8, shift=4)
    return out


class MapSampler(Hook):
    """Exploration only (a STOP is sent as a left turn, so the agent keeps mapping the house) and,
    every ``every`` steps, the agent's map window as the predictor reads it with the goal targets
    of the episode's house (``inputs`` uint8, ``targets``, ``steps``)."""

    def __init__(self, cfg, spec, goals: tuple[str, ...], every: int):
        self.cfg, self.spec, self.goals, self.every = cfg, spec, goals, every
        self.inputs: list[np.ndarray] = []
        self.targets: list[np.ndarray] = []
        self.steps: list[int] = []

    def before_step(self, env, step, obs, action: int) -> int:
        from calnav.envs.task import Action

        return int(Action.TURN_LEFT) if action == int(Action.STOP) else action

    def after_step(self, env, step, action: int, obs, info, n: int) -> None:
        from calnav.agent.prediction import crop_origin, map_input, pool_factor
        from calnav.agent.semantic_map import MapChannels
        from calnav.envs.task import COMPASS, GPS, gps_compass_to_xy_yaw

        if n % self.every:
            return
        cell_m, st = step.cell_m, step.state
        xy, _ = gps_compass_to_xy_yaw(obs[GPS], obs[COMPASS])   # where the move took it
        rc = st.to_cell(xy, cell_m)
        maps = {"obstacle": st.obstacles(), "explored": st.channels[MapChannels.EXPLORED],
                "visited": st.channels[MapChannels.VISITED]}
        x = map_input(maps, st.semantic, rc, self.spec, cell_m)
        self.inputs.append(np.round(np.clip(x, 0, 1) * 255).astype(np.uint8))
        corner = crop_origin(rc, self.spec, pool_factor(self.spec, cell_m))
        ep, scene = env.unwrapped.episode, env.unwrapped.scene
        self.targets.append(goal_targets(scene, ep, st.origin, corner, self.spec, cell_m, self.goals))
        self.steps.append(n)


def collect_episode(task: CollectTask) -> dict:
    """Run one exploring episode on this worker (``eval.rollout`` with a ``MapSampler``);
    returns its arrays (see the module docstring)."""
    from calnav.agent.prediction import PredictorSpec
    from calnav.agent.segmenters.base import goal_categories
    from calnav.eval.config import agent_setup
    from calnav.eval.objectnav.run import _warm_env_agent
    from calnav.eval.rollout import rollout

    cfg = task.cfg
    env, agent = _warm_env_agent(cfg, agent_setup(cfg, "peanut"), upto=task.upto)
    goals = goal_categories()
    spec = PredictorSpec(class_names=agent.class_names, goal_categories=goals)
    sampler = MapSampler(cfg, spec, goals, task.every)
    rollout(env, agent, task.index, [sampler], max_steps=task.steps)
    ep = env.unwrapped.episode
    return {"inputs": np.stack(sampler.inputs), "targets": np.stack(sampler.targets),
            "steps": np.array(sampler.steps, np.int32),
            "meta": {"episode_id": ep.episode_id, "scene": ep.scene_id, "spec": spec.to_dict(),
                     "map_type": cfg.agent.map_type, "fusion": cfg.mapping.fusion, "segmenter": cfg.agent.segmenter}}


def collect_configs(args) -> list:
    """The config ``calnav collect-maps`` runs: ``--split`` / ``--steps`` (their defaults: train,
    250) as ``env.split`` / ``env.max_episode_steps`` (the command's shorthands)."""
    from calnav.eval.shorthands import load_command_config

    return [load_command_config(args)]


def main_collect_maps(args, configs) -> None:
    """``configs``: ``collect_configs(args)``, checked by the preflight."""
    from calnav.common.npz import save_versioned_npz
    from calnav.eval.runner import raise_failures, run_tasks
    from calnav.eval.episodes import episode_indices

    cfg = configs[0]
    steps = cfg.env.max_episode_steps - 1   # --steps: its shorthand sets env.max_episode_steps = STEPS + 1
    if steps < 1 or not 1 <= args.every <= steps:
        raise ValueError(f"--steps must be >= 1 and --every in [1, --steps], got {steps} / {args.every}")
    out = Path(args.output)
    indices = episode_indices(str(args.episodes), cfg.env, cfg.run)
    with ResultsDir(out, cfg, force=args.force, discard=("episodes",), files=()):
        todo = [i for i in indices if not episode_file(out, i).exists()]
        tasks = [CollectTask(cfg, i, steps, args.every, max(indices) + 1) for i in todo]

        def save(task: CollectTask, res: dict) -> None:
            save_versioned_npz(episode_file(out, task.index), {k: res[k] for k in ("inputs", "targets", "steps")},
                               res["meta"], MAPS_FORMAT)

        failures = run_tasks(collect_episode, tasks, cfg.run, save=save, desc="collect maps", unit="ep",
                             total=len(indices))
    raise_failures(failures, "episode", name=lambda task: f"episode {task.index}")
    print(f"maps: {len(indices)} episodes in {out} ({len(todo)} collected now)")


@dataclass
class CollectMapsArgs:
    """``calnav collect-maps``'s flags."""

    split: Literal["train", "val"] | None = arg(None, "houses explored (val: held-out maps); shorthand for env.split "
                                                      "(default train)", sets="env.split", sets_default="train")
    episodes: str = arg("0:200", "the split's episodes: N or A:B (default 0:200)")
    # the rollout's STEPS steps fit the limit; STEPS and --every are checked together by main_collect_maps
    steps: int | None = arg(None, "steps per episode (default 250); shorthand for env.max_episode_steps=STEPS+1",
                            sets="env.max_episode_steps", convert=lambda n: n + 1, sets_default=250)
    every: int = arg(25, "a snapshot every this many steps (default 25, PEANUT's)")
    output: str = arg(REQUIRED, "results directory (episodes/<index>.npz; resumable)")
    force: bool = arg(False, "discard the maps of a different config in --output")


COMMAND = Command(CollectMapsArgs, main_collect_maps, collect_configs, config="configs/objectnav.yaml")
