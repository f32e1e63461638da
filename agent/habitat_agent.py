"""calnav's agents as ``habitat.Agent`` s, for habitat-lab's ``habitat.Benchmark`` /
``habitat.Env`` -- on calnav houses (``CalnavSim-v0``) or on habitat-sim with HM3D.

``HabitatAgent(navigator)`` wraps the agent as a library (``agent.navigator.Navigator``, of any
agent of ``agent.registry.AGENTS``; ``calnav habitat-benchmark`` builds it as ``calnav objectnav``
does). ``HabitatPeanutAgent(setup)`` is the PEANUT-like agent so wrapped: ``setup`` is its
``agent.setup.AgentSetup`` (``agent``: segmenter, map type, thresholds; ``mapping``: fusion +
GLFS parameters -- as ``calnav objectnav``) whose ``sensor`` states the task's sensor facts;
calnav's commands make it with ``eval.config.agent_setup`` from a config whose ``env`` section
is ``envs.habitat_config.env_config_from_habitat(habitat_cfg, cfg.env)`` (which needs no
simulator). What crosses the boundary, and how:

- ``reset()`` takes no observations in habitat-lab: it is the Navigator's ``reset()``, which
  takes the goal category and the start pose from the first observations (the oracle then
  starts on the episode's scene);
- observations are passed through: the agent reads Habitat's keys (``envs.task.HABITAT_KEYS``:
  rgb (H, W, 3) uint8, depth (H, W, 1), gps (2,), compass (1,), objectgoal (1,)); only
  ``semantic`` (for the gt / noisy segmenters) changes shape, habitat's (H, W, 1) -> (H, W);
- depth: habitat-lab normalises it by default (``normalize_depth``: (d - min) / (max - min),
  clipped to [0, 1]); ``sensor.normalize_depth`` / ``min_depth_m`` / ``max_depth_m`` (from the
  depth sensor config) let the agent map it back to metres, 0 and 1 read as invalid;
- pose: the agent's map lives in the episode-start frame; gps (forward, right) and compass
  (ccw) give position and heading in it (``envs.task.gps_compass_to_xy_yaw``), the camera
  height ``sensor.camera_height_m`` comes from the sensor position;
- intrinsics: a pinhole of ``sensor.resolution`` and ``sensor.hfov_deg`` (the sensor config);
- actions: calnav's ids are habitat-lab's ObjectNav action order; the agent returns the action
  *name* (``stop``, ``move_forward``, ``turn_left``, ``turn_right``, ``look_up``,
  ``look_down``), which habitat-lab resolves whatever order a config lists them in.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from calnav.agent.navigator import Navigator
from calnav.agent.setup import AgentSetup
from calnav.common.habitat_import import import_habitat
from calnav.envs.task import HABITAT_KEYS, SEMANTIC, Action

habitat = import_habitat()


def habitat_action(action: int) -> str:
    """calnav action id -> habitat-lab's task action name (``Action.MOVE_FORWARD`` ->
    ``move_forward``)."""
    return Action(int(action)).name.lower()


def from_habitat_observations(observations) -> dict:
    """Habitat observations -> the agent's: Habitat's keys as they are, ``semantic`` (H, W, 1)
    -> (H, W) when present; other keys (sensors the agent does not read) are dropped."""
    obs = {k: observations[k] for k in HABITAT_KEYS if k in observations}
    if SEMANTIC in observations:
        sem = np.asarray(observations[SEMANTIC])
        obs[SEMANTIC] = sem[..., 0] if sem.ndim == 3 else sem
    return obs


class HabitatAgent(habitat.Agent):
    """A ``Navigator`` behind habitat-lab's ``Agent`` interface (see the module docstring);
    ``navigator`` is the wrapped one, ``decision`` its last step (``agent.navigator.Decision``,
    with the agent's ``agent.step.Step``; None before the first)."""

    def __init__(self, navigator: Navigator):
        self.navigator = navigator
        self.navigator.reset()
        self.decision = None

    def reset(self) -> None:
        """Start a new episode: goal and start pose come with the first observations."""
        self.navigator.reset()
        self.decision = None

    def act(self, observations) -> dict:
        """habitat-lab's action dict ``{"action": name}`` for these observations."""
        self.decision = self.navigator.observe(from_habitat_observations(observations))
        return {"action": habitat_action(self.decision.action)}


class HabitatPeanutAgent(HabitatAgent):
    """The PEANUT-like agent of ``setup`` (``agent.setup.AgentSetup``; ``name`` peanut) as a
    ``habitat.Agent``."""

    def __init__(self, setup: AgentSetup):
        super().__init__(Navigator(dataclasses.replace(setup, name="peanut")))
