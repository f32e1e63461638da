"""The one episode loop: every command that steps an env runs its episodes through ``rollout``.

Reset the env on an episode, reset the agent on the first observation, then act and step until
the episode ends (or ``max_steps`` steps, for commands that look at a prefix of an episode).
What a command does beside the loop -- write a video or a Rerun recording, collect maps for the
predictor, record the path, time the steps -- is a ``Hook``; a hook that changes the action
says so (``before_step`` returns the action that is sent). Hooks are called in order.

    result = rollout(env, agent, index, hooks=[VideoHook(path)])
    result.info["spl"], result.steps, result.terminated

An agent is anything with ``reset(obs)`` and ``act(obs) -> Step`` (``agent.contract.Agent``,
``agent.step.Step``: the action and what the agent decided it from, which the hooks read;
the agents of ``agent.registry.AGENTS``, a composite that drives several agents in lockstep);
it gets the env's observation as it is and splits off the privileged part itself
(``agent.contract.split_observation``), so the loop also runs envs with other observations.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable

from calnav.agent.contract import Agent
from calnav.agent.step import Step


class Hook:
    """A rollout's side work; every method is a no-op here, a hook overrides what it needs."""

    def on_reset(self, env, agent, obs: dict, info: dict) -> None:
        """After the env and the agent are reset, before the first action."""

    def before_step(self, env, step: Step, obs: dict, action: int) -> int:
        """After the agent's ``step`` on ``obs`` (``action``: its action, or an earlier hook's);
        returns the action to send."""
        return action

    def after_step(self, env, step: Step, action: int, obs: dict, info: dict, n: int) -> None:
        """After the env took ``action`` (the ``n``-th, from 1) for the agent's ``step``;
        ``obs`` / ``info`` are new."""

    def on_end(self, env, agent, result: "RolloutResult") -> None:
        """After the last step."""


@dataclass
class RolloutResult:
    """How an episode ended: the env's last ``info`` (the task's measures), the number of
    steps taken, and whether it ended by STOP (``terminated``) or by the env's step limit
    (``truncated``); neither when ``max_steps`` cut it short."""

    index: int
    info: dict[str, Any]
    steps: int
    terminated: bool
    truncated: bool


def rollout(env, agent: Agent, index: int, hooks: Iterable[Hook] = (), max_steps: int = 0) -> RolloutResult:
    """Run episode ``index`` of ``env`` (a gymnasium env whose ``reset`` takes
    ``options={"episode_index": index}``) with ``agent``; ``max_steps`` > 0 stops after that many
    steps even if the episode goes on."""
    hooks = list(hooks)
    obs, info = env.reset(options={"episode_index": index})
    agent.reset(obs)
    for hook in hooks:
        hook.on_reset(env, agent, obs, info)
    steps, terminated, truncated = 0, False, False
    while not (terminated or truncated) and not (max_steps and steps >= max_steps):
        step = agent.act(obs)
        action = step.action
        for hook in hooks:
            action = hook.before_step(env, step, obs, action)
        obs, _, terminated, truncated, info = env.step(action)
        steps += 1
        for hook in hooks:
            hook.after_step(env, step, action, obs, info, steps)
    result = RolloutResult(index, info, steps, terminated, truncated)
    for hook in hooks:
        hook.on_end(env, agent, result)
    return result
