"""The agent's parts chosen by a config key, one ``Registry`` each (``common.registry``):

| registry | config key | parts |
|---|---|---|
| ``MAP_BUILDERS`` | ``agent.map_type`` | ``fused``, ``ndf`` (``agent.semantic_map``) |
| ``GOAL_SELECTORS`` | ``agent.exploration`` | ``frontier``, ``prediction`` (``agent.goal_selection``) |
| ``DECISIONS`` | ``agent.decision`` | ``threshold``, ``evidence`` (``agent.evidence``) |
| ``GOAL_CHOICES`` | ``agent.goal_choice`` | ``largest`` (``agent.goal_detection``), ``evidence`` (``agent.evidence``) |
| ``AGENTS`` | ``run.agent`` | ``peanut`` (``agent.policy``), ``oracle`` (``agent.oracle``) |

Every part is a lazy ``"module:attribute"`` reference, so this module imports nothing heavy:
the configs check a name against it (``REGISTRY.check``) before torch, Open3D or a simulator
loads. ``AGENTS`` is the one agent registry of ``calnav objectnav``, ``calnav view-episode``,
``calnav collect-maps`` and ``calnav habitat-benchmark`` (which wraps the agent as a
``habitat.Agent``: ``agent.habitat_agent.HabitatAgent``); an agent is built from its typed
setup by ``agent.setup.build_agent``.
"""
from __future__ import annotations

from calnav.common.registry import Registry

# A map builder: ``cls(agent_cfg, mapping_cfg, class_names, depth_range_m)`` with ``new_state(start_xy)``
# and ``update(state, frame, pose)`` (``agent.semantic_map.MapBuilder``).
MAP_BUILDERS: Registry[type] = Registry("map type", key="agent.map_type")
MAP_BUILDERS.add("fused", "calnav.agent.semantic_map:FusedMapBuilder",
                 "3D calibrated fusion (mapping.fusion) projected to the ground plane")
MAP_BUILDERS.add("ndf", "calnav.agent.semantic_map:NdfMapBuilder",
                 "SemExp / PEANUT baseline: per-frame 2D projection, max over time")

# A goal selector: ``cls(agent_cfg, class_names, goal_names)`` (``agent.goal_selection.FrontierSelector``).
GOAL_SELECTORS: Registry[type] = Registry("exploration", key="agent.exploration")
GOAL_SELECTORS.add("frontier", "calnav.agent.goal_selection:FrontierSelector",
                   "the frontier of best size / distance utility")
GOAL_SELECTORS.add("prediction", "calnav.agent.goal_selection:PredictionSelector",
                   "PEANUT's target prediction, frontiers when it offers nothing")

# A goal decision: ``cls(agent_cfg, temperature)`` with ``reset(n)``, ``observe(state, frame, pose,
# goal_channel)`` and ``review(move, det, state, goal_channel, win, agent_rc, free)`` (``agent.evidence``).
DECISIONS: Registry[type] = Registry("decision", key="agent.decision")
DECISIONS.add("threshold", "calnav.agent.evidence:ThresholdDecision",
              "STOP on arrival at a component above agent.goal_threshold (PEANUT)")
DECISIONS.add("evidence", "calnav.agent.evidence:EvidenceDecision",
              "an uncertainty test on the object's evidence over views before STOP; a second look, then reject")

# A goal choice among the components above the goal threshold: ``cls(agent_cfg, n)`` per episode map
# with ``picker(confidence, win, decision)`` -> None (the largest) or ``pick(masks, areas) -> index``.
GOAL_CHOICES: Registry[type] = Registry("goal choice", key="agent.goal_choice")
GOAL_CHOICES.add("largest", "calnav.agent.goal_detection:LargestChoice",
                 "the largest component above agent.goal_threshold (PEANUT)")
GOAL_CHOICES.add("evidence", "calnav.agent.evidence:EvidenceChoice",
                 "the component whose evidence over views is strongest (needs agent.decision=evidence)")

# An agent class: ``cls.from_setup(setup)`` (``setup``: an ``agent.setup.AgentSetup``), or
# ``cls.from_setup(setup, simulator=...)`` for a class declaring ``privileged = (SIMULATOR,)``.
AGENTS: Registry[type] = Registry("agent", key="run.agent")
AGENTS.add("peanut", "calnav.agent.policy:PeanutAgent", "the PEANUT-like semantic-map agent (agent.*)")
AGENTS.add("oracle", "calnav.agent.oracle:OracleAgent", "the shortest-path follower (privileged: the simulator)")
# The agent an AGENTS class builds instead in a house with storeys (``env.dataset.storeys > 1``),
# so that single-storey runs keep their class and every action they took.
STOREY_AGENTS: Registry[type] = Registry("agent for storeys", key="run.agent")
STOREY_AGENTS.add("peanut", "calnav.agent.storey_policy:StoreyPeanutAgent",
                  "the PEANUT-like agent with a map per storey and stairs (agent.storeys)")

