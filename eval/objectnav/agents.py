"""Agents that ``calnav objectnav`` can run, chosen by name (one registry)."""
from __future__ import annotations

from typing import Callable

AgentFactory = Callable[..., object]


def _oracle(env, cfg):
    from calnav.envs.oracle import OracleAgent

    return OracleAgent(env)


def _peanut(env, cfg):
    """The semantic-map agent; it gets only the config (observations come through act)."""
    from calnav.agent.policy import PeanutAgent

    return PeanutAgent(cfg, cfg.run.device)


AGENTS: dict[str, AgentFactory] = {"oracle": _oracle, "peanut": _peanut}


def make_agent(name: str, env, cfg):
    """Agent ``name`` for ``env`` (a gymnasium env) configured by ``cfg`` (a Config)."""
    if name not in AGENTS:
        raise ValueError(f"unknown agent {name!r}; valid agents: {', '.join(AGENTS)}")
    return AGENTS[name](env, cfg)
