"""Rollout hooks of the ObjectNav commands (``eval.rollout``): an episode's video, its Rerun
recording and its path. Each only reads the agent's step (``agent.step.Step``) and the env: the actions, hence the metrics,
are the same with them as without."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from calnav.eval.rollout import Hook, RolloutResult


def episode_file_stem(episode_id: str) -> str:
    """``episode_id`` as a portable file name (':' and the like become '_')."""
    return re.sub(r"[^\w.-]", "_", episode_id)


class VideoHook(Hook):
    """One ``agent.visualize.render_panel`` per step (drawn after the agent acts, before the env
    steps) to ``<directory>/<episode>.mp4``; ``path`` is the file written (None: no frame)."""

    def __init__(self, directory: Path):
        self.directory, self.video, self.path = Path(directory), None, None

    def on_reset(self, env, agent, obs, info) -> None:
        from calnav.agent.visualize import EpisodeVideo

        self.video = EpisodeVideo(self.directory / f"{episode_file_stem(env.unwrapped.episode.episode_id)}.mp4")

    def before_step(self, env, step, obs, action: int) -> int:
        from calnav.agent.visualize import render_panel

        self.video.add(render_panel(step))
        return action

    def on_end(self, env, agent, result: RolloutResult) -> None:
        self.path = self.video.write() if self.video.frames else None


class RerunHook(Hook):
    """The episode recorded to ``<directory>/<episode>.rrd`` (``agent.recording``); ``path`` is
    the file written."""

    def __init__(self, directory: Path):
        self.directory, self.recording, self.path = Path(directory), None, None

    def on_reset(self, env, agent, obs, info) -> None:
        from calnav.agent.recording import EpisodeRecording

        episode_id = env.unwrapped.episode.episode_id
        self.recording = EpisodeRecording(self.directory / f"{episode_file_stem(episode_id)}.rrd", agent.class_names,
                                          episode_id)

    def after_step(self, env, step, action: int, obs, info, n: int) -> None:
        self.recording.step(step, action, info)

    def on_end(self, env, agent, result: RolloutResult) -> None:
        self.path = self.recording.close()


class PathHook(Hook):
    """The agent's positions (the start, then after every step; (N, 2) metres, ``path``) and
    every observation (``frames``), for ``calnav view-episode``'s drawings."""

    def __init__(self):
        self.positions: list[np.ndarray] = []
        self.frames: list[dict] = []

    @property
    def path(self) -> np.ndarray:
        return np.array(self.positions)

    def on_reset(self, env, agent, obs, info) -> None:
        self.positions, self.frames = [env.unwrapped.position.copy()], [obs]

    def after_step(self, env, step, action: int, obs, info, n: int) -> None:
        self.positions.append(env.unwrapped.position.copy())
        self.frames.append(obs)
