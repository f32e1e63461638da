"""Agents that ``calnav habitat-benchmark`` can run, chosen by name (the names of
``eval.objectnav.agents.AGENTS``): each is a ``habitat.Agent`` (``reset()`` without
observations, ``act(observations)``)."""
from __future__ import annotations

from typing import Callable

from calnav.common.habitat_import import import_habitat

habitat = import_habitat()


class HabitatOracleAgent(habitat.Agent):
    """calnav's oracle (``envs.oracle.ShortestPathFollower``) through habitat-lab. Privileged:
    reads the ``CalnavSim-v0`` pose and the episode's view points from ``env`` (a habitat.Env),
    as ``envs.oracle.OracleAgent`` reads calnav's env; it takes the same actions."""

    name = "oracle"

    def __init__(self, env, env_cfg):
        """env: a habitat.Env on CalnavSim-v0; env_cfg: the EnvConfig of the habitat config
        (``envs.habitat_config.env_config_from_habitat``: step, turns, success distance)."""
        self.env, self.env_cfg = env, env_cfg

    def reset(self) -> None:
        from calnav.envs.oracle import ShortestPathFollower

        self.follower = ShortestPathFollower(self.env.sim.navgrid, self.env_cfg)
        self.steps = 0

    def act(self, observations) -> int:
        from calnav.envs.task import Action

        sim, ep = self.env.sim, self.env.current_episode
        self.steps += 1
        if self.steps >= self.env_cfg.max_episode_steps:
            return int(Action.STOP)  # forced STOP on the last step, as envs.oracle.OracleAgent
        field = sim.goal_field([v.agent_state.position for g in ep.goals for v in g.view_points])
        return int(self.follower.next_action(sim.position, sim.yaw, field))


def _oracle(env, cfg):
    return HabitatOracleAgent(env, cfg.env)


def _peanut(env, cfg):
    from calnav.agent.habitat_agent import HabitatPeanutAgent

    return HabitatPeanutAgent(cfg, cfg.run.device)


HABITAT_AGENTS: dict[str, Callable] = {"oracle": _oracle, "peanut": _peanut}


def make_habitat_agent(name: str, env, cfg):
    """Agent ``name`` for ``env`` (a habitat.Env) configured by ``cfg`` (a Config whose ``env``
    follows the habitat config)."""
    if name not in HABITAT_AGENTS:
        raise ValueError(f"unknown agent {name!r}; valid agents: {', '.join(HABITAT_AGENTS)}")
    return HABITAT_AGENTS[name](env, cfg)
