"""``OracleAgent`` (``run.agent=oracle``): the shortest path to the goal, for validating
episodes, geodesics and metrics. It is privileged by declaration (``privileged = (SIMULATOR,)``,
``agent.contract``): ``agent.setup.build_agent`` hands it the env's ``SimulatorHandle``
(``envs.task``: the simulator's shortest-path follower on its true pose), and it reads nothing
of the observations. Like PEANUT, it calls STOP on the episode's last step.
"""
from __future__ import annotations

from typing import Mapping

from calnav.agent.contract import SIMULATOR
from calnav.agent.setup import AgentSetup
from calnav.agent.step import Step
from calnav.envs.task import Action, SimulatorHandle


class OracleAgent:
    """``OracleAgent(simulator)``; ``reset(obs)`` / ``act(obs) -> Step`` (``agent.contract.Agent``:
    the action alone, a map-less ``agent.step.Step``)."""

    name = "oracle"
    privileged = (SIMULATOR,)
    class_names: tuple[str, ...] = ()   # it keeps no map
    needs_semantic = False

    def __init__(self, simulator: SimulatorHandle, categories: tuple[str, ...] = ()):
        self.simulator = simulator
        self.categories = categories   # the task's goal categories; () = calnav's
        self.steps = 0

    @classmethod
    def from_setup(cls, setup: AgentSetup, simulator: SimulatorHandle) -> "OracleAgent":
        """The registry's builder (``agent.setup.build_agent``); the setup sets only the task's
        goal categories (``agent.goal_categories``)."""
        from calnav.agent.segmenters.base import task_goal_categories

        return cls(simulator, task_goal_categories(setup.agent))

    def goal_names(self) -> tuple[str, ...]:
        """The goal categories it can be asked for: every ObjectNav goal (it reads the scene)."""
        from calnav.agent.segmenters.base import goal_categories

        return self.categories or goal_categories()

    def reset(self, obs: Mapping) -> None:
        self.simulator.reset()
        self.steps = 0

    def act(self, obs: Mapping) -> Step:
        self.steps += 1   # this action is the episode's steps-th
        if self.steps >= self.simulator.max_episode_steps:
            return Step(int(Action.STOP), self.steps)  # forced STOP on the last step, as PEANUT does
        return Step(int(self.simulator.shortest_path_action()), self.steps)
