"""What the agent is built from: ``AgentSetup``, one typed object per agent.

    from calnav.agent.config import AgentConfig
    from calnav.agent.setup import AgentSetup, SensorSetup

    setup = AgentSetup(agent=AgentConfig(segmenter="learned_rgb"),
                       sensor=SensorSetup(resolution=(640, 480), hfov_deg=79.0, camera_height_m=0.88))

``AgentSetup`` holds the agent's own sections (``agent``, ``segmenter``, ``mapping``: the YAML
sections of those names), the facts of the task the agent may know (``SensorSetup``: its camera
and depth range, its action sizes, the step limit, the storeys: never simulator state), the
``run.agent`` name it builds and the torch device. Every part is validated where it is made
(its dataclass's ``__post_init__``), so a setup pickles to a worker as it is, checked once.
calnav's commands make it from their root config with ``eval.config.agent_setup(cfg)``; a robot
program makes it with these constructors (``docs/robot.md``). ``build_agent(setup)`` builds
the agent it names.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from calnav.agent.config import AgentConfig
from calnav.agent.contract import SIMULATOR, Agent, declared_privileged
from calnav.agent.registry import AGENTS
from calnav.agent.segmenters.base import SegmenterConfig
from calnav.agent.sensors import SensorModel
from calnav.envs.task import SimulatorHandle
from calnav.mapping.config import MappingConfig


@dataclass(frozen=True)
class SensorSetup:
    """The task's facts the agent may know; defaults are calnav's env's (``envs.config.EnvConfig``).
    resolution (W, H) pixels; hfov_deg degrees (pinhole, principal point at the centre);
    camera_height_m metres above the floor (level camera); depth valid in [min_depth_m,
    max_depth_m] metres; normalize_depth: depth arrives as Habitat's normalised [0, 1];
    forward_step_m metres and turn_angle_deg degrees per action; view_point_radius_m: the task's
    goal view points lie within this of the object, metres; max_episode_steps actions; storeys
    of the house (> 1: the agent with a map per storey, ``agent.storey_policy``)."""

    resolution: tuple[int, int] = (640, 480)
    hfov_deg: float = 79.0
    camera_height_m: float = 0.88
    min_depth_m: float = 0.5
    max_depth_m: float = 5.0
    normalize_depth: bool = False
    forward_step_m: float = 0.25
    turn_angle_deg: float = 30.0
    view_point_radius_m: float = 1.0
    max_episode_steps: int = 500
    storeys: int = 1

    def __post_init__(self) -> None:
        w, h = self.resolution
        checks = (("resolution", w >= 1 and h >= 1, "two positive pixel counts (W, H)"),
                  ("hfov_deg", 0 < self.hfov_deg < 180, "in (0, 180) degrees"),
                  ("camera_height_m", math.isfinite(self.camera_height_m) and self.camera_height_m >= 0, ">= 0 metres"),
                  ("max_depth_m", 0 <= self.min_depth_m < self.max_depth_m < math.inf,
                   "finite and above min_depth_m >= 0 metres"),
                  ("forward_step_m", 0 < self.forward_step_m < math.inf, "> 0 metres"),
                  ("turn_angle_deg", 0 < self.turn_angle_deg <= 180, "in (0, 180] degrees"),
                  ("view_point_radius_m", 0 < self.view_point_radius_m < math.inf, "> 0 metres"),
                  ("max_episode_steps", self.max_episode_steps >= 1, ">= 1 actions"),
                  ("storeys", self.storeys >= 1, ">= 1"))
        for key, ok, valid in checks:
            if not ok:
                raise ValueError(f"sensor.{key} must be {valid}, got {getattr(self, key)!r}")

    @property
    def model(self) -> SensorModel:
        """The camera model the agent reads its observations with (``agent.sensors``)."""
        w, h = self.resolution
        return SensorModel((int(w), int(h)), float(self.hfov_deg), float(self.camera_height_m),
                           float(self.min_depth_m), float(self.max_depth_m), bool(self.normalize_depth))


@dataclass(frozen=True)
class AgentSetup:
    """Everything an agent of ``agent.registry.AGENTS`` is built from (module docstring):
    ``name`` the ``run.agent`` to build, ``device`` the torch device of its learned models."""

    agent: AgentConfig = field(default_factory=AgentConfig)
    segmenter: SegmenterConfig = field(default_factory=SegmenterConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    sensor: SensorSetup = field(default_factory=SensorSetup)
    name: str = "peanut"
    device: str = "cpu"

    def __post_init__(self) -> None:
        AGENTS.check(self.name)   # the name only: the agent loads when it is built


def build_agent(setup: AgentSetup, simulator: SimulatorHandle | None = None) -> Agent:
    """The agent ``setup.name`` (``agent.registry.AGENTS``) built from ``setup``. ``simulator``:
    the env's privileged handle (``envs.task.SimulatorHandle``), handed only to an agent class
    that declares ``SIMULATOR`` (``agent.contract``); such an agent without one is a one-line
    ValueError."""
    cls = AGENTS.get(setup.name)
    if SIMULATOR not in declared_privileged(cls):
        return cls.from_setup(setup)
    if simulator is None:
        raise ValueError(f"agent {setup.name!r} needs the simulator's privileged handle (envs.task.SimulatorHandle), "
                         "which this env does not provide")
    return cls.from_setup(setup, simulator=simulator)
