"""What an agent and its parts may read, in one file: the ``Observation`` (Habitat's ObjectNav
keys), the ``Privileged`` rest of the env's observation, how a part declares the privileged
data it needs, and the ``Agent`` protocol every agent of ``agent.registry.AGENTS`` follows.

The env's observation (``envs.task``) holds Habitat's keys (``HABITAT_KEYS``: rgb, depth, gps,
compass, objectgoal; ``SEMANTIC`` when the semantic sensor is on) and privileged data Habitat
does not give: the simulator's ``camera_pose`` / ``camera_intrinsics`` (``DEBUG_KEYS``) and an
``instance`` image a caller may add (ground-truth instance ids; calnav's env does not emit it).
An agent splits it once, where it receives it (``split_observation``):

- its parts read the ``Observation``, a read-only mapping of Habitat's keys only -- asking it
  for ``camera_pose`` is a KeyError, so no decision can depend on privileged data;
- the ``Privileged`` part reaches a part only through ``handed(part, privileged)``, which keeps
  just what the part's *class* declares (``privileged = (CAMERA_POSE, ...)``): today the
  ``noisy`` segmenter (its world-anchored errors), nothing else of the PEANUT-like agent;
- the simulator itself (``SIMULATOR``: ``envs.task.SimulatorHandle``, the env's privileged
  handle) is handed at construction, by ``agent.setup.build_agent``, to an agent class that
  declares it: the oracle (``agent.oracle``).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any, Iterator, Protocol

import numpy as np

from calnav.envs.task import (CAMERA_INTRINSICS, CAMERA_POSE, COMPASS, DEBUG_KEYS, DEPTH, GPS, HABITAT_KEYS, OBJECTGOAL,
                              RGB, SEMANTIC, require_keys)

INSTANCE = "instance"      # ground-truth instance ids (H, W) int, -1 none: a caller's extra, privileged
SIMULATOR = "simulator"    # the env's privileged handle (envs.task.SimulatorHandle), handed at construction
# privileged data that comes with an observation: Privileged's fields, in order (a test checks)
OBSERVED_PRIVILEGED: tuple[str, ...] = (*DEBUG_KEYS, INSTANCE)
PRIVILEGED_NAMES: tuple[str, ...] = (*OBSERVED_PRIVILEGED, SIMULATOR)


@dataclass(frozen=True, eq=False)
class Observation(Mapping):
    """Habitat's ObjectNav observation, as a read-only mapping of its keys (``obs[GPS]``):
    rgb (H, W, 3) uint8; depth (H, W, 1) float32 (metres, or normalised: ``agent.sensors``);
    gps (2,) float32 (forward, right) metres; compass (1,) float32 radians; objectgoal (1,)
    int64; semantic (H, W) int class ids, -1 void (the semantic sensor, when on; else absent).
    The arrays are the env's own (not copied)."""

    rgb: Any
    depth: Any
    gps: Any
    compass: Any
    objectgoal: Any
    semantic: Any = None

    def __getitem__(self, key: str) -> Any:
        value = getattr(self, key, None) if key in _OBSERVATION_KEYS else None
        if value is None:
            raise KeyError(key)
        return value

    def __iter__(self) -> Iterator[str]:
        return (k for k in _OBSERVATION_KEYS if getattr(self, k) is not None)

    def __len__(self) -> int:
        return sum(1 for _ in self)


_OBSERVATION_KEYS: tuple[str, ...] = (*HABITAT_KEYS, SEMANTIC)   # Observation's fields, in order (a test checks)


@dataclass(frozen=True)
class Privileged:
    """The privileged rest of an observation (each None when absent or not handed): the
    simulator's world-from-camera ``camera_pose`` (4, 4) float64 (OpenCV axes),
    ``camera_intrinsics`` (3, 3) float64, and ground-truth ``instance`` ids (H, W) int."""

    camera_pose: np.ndarray | None = None
    camera_intrinsics: np.ndarray | None = None
    instance: np.ndarray | None = None

    def only(self, names: tuple[str, ...]) -> "Privileged":
        """A copy holding just the fields ``names`` (the rest None)."""
        return replace(self, **{f.name: None for f in fields(self) if f.name not in names})


def split_observation(obs: Mapping) -> tuple[Observation, Privileged]:
    """The env's observation dict -> (Habitat's observation, the privileged part); other keys
    are dropped. A missing Habitat key is a one-line KeyError naming it (``require_keys``)."""
    if isinstance(obs, Observation):
        return obs, Privileged()
    require_keys(obs, HABITAT_KEYS)
    observation = Observation(obs[RGB], obs[DEPTH], obs[GPS], obs[COMPASS], obs[OBJECTGOAL], obs.get(SEMANTIC))
    return observation, Privileged(obs.get(CAMERA_POSE), obs.get(CAMERA_INTRINSICS), obs.get(INSTANCE))


def declared_privileged(part: Any) -> tuple[str, ...]:
    """The privileged data ``part``'s class (or ``part``, a class) declares it needs, its class
    attribute ``privileged`` (default none); a name that is not privileged data is a ValueError."""
    cls = part if isinstance(part, type) else type(part)
    names = tuple(getattr(cls, "privileged", ()))
    unknown = [n for n in names if n not in PRIVILEGED_NAMES]
    if unknown:
        raise ValueError(f"{cls.__name__} declares unknown privileged data {', '.join(map(repr, unknown))}; "
                         f"valid: {', '.join(PRIVILEGED_NAMES)}")
    return names


def handed(part: Any, privileged: Privileged | None) -> Privileged:
    """What of ``privileged`` ``part`` is handed: the fields its class declares, nothing else."""
    if privileged is None:
        return Privileged()
    return privileged.only(declared_privileged(part))


if TYPE_CHECKING:
    from calnav.agent.step import Step


class Agent(Protocol):
    """An ObjectNav agent: ``reset(obs)`` on an episode's first observation, then
    ``act(obs) -> Step`` per step (``agent.step.Step``: its ``envs.task.Action`` id and what it
    decided it from). ``obs`` is the env's observation
    dict; the agent splits it (``split_observation``). A class may declare
    ``privileged = (SIMULATOR,)`` to be built with the env's ``SimulatorHandle``."""

    def reset(self, obs: Mapping) -> None: ...

    def act(self, obs: Mapping) -> "Step": ...
