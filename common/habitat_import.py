"""Import habitat-lab without habitat-sim: the one place that knows how.

habitat-lab (the pure-Python ``habitat-lab`` package) imports ``magnum`` -- which ships only
with habitat-sim -- at module level in four places that ObjectNav never uses:

- ``habitat.sims.habitat_simulator.object_state_machine`` (imported by the package that
  registers habitat-sim's ``Sim-v0``),
- ``habitat.tasks.rearrange`` (``_try_register_rearrange_task`` imports the rearrange actions),
- ``habitat.core.batch_rendering.env_batch_renderer`` (imported by ``habitat.core.vector_env``),
- ``habitat.gym.gym_wrapper`` (imported by ``habitat.core.environments``).

When habitat-sim is absent, ``import_habitat`` puts a small stand-in for each into
``sys.modules`` before importing habitat, so ``habitat.Env`` / ``habitat.Benchmark`` with the
ObjectNav task, its sensors and measures import and run. Using anything a stand-in replaces
(rearrangement tasks, batch rendering, the gym wrapper, habitat-sim's simulator) raises an
ImportError that says habitat-sim is needed. With habitat-sim installed nothing is stubbed.
"""
from __future__ import annotations

import importlib.util
import sys
import types

INSTALL_HINT = ("habitat-lab is not installed in this Python: run `make habitat-setup` (creates "
                ".venv-habitat) or `pip install -e \".[habitat]\"` in a venv with numpy 1.26 "
                "(habitat-lab pins numpy==1.26.4)")

# module -> names its importers take from it
STUBBED_MODULES: dict[str, tuple[str, ...]] = {
    "habitat.sims.habitat_simulator.object_state_machine": ("ObjectStateMachine",),
    "habitat.tasks.rearrange": ("_try_register_rearrange_task",),
    "habitat.core.batch_rendering.env_batch_renderer": ("EnvBatchRenderer",),
    "habitat.gym.gym_wrapper": ("HabGymWrapper",),
}
STUB_MARKER = "__calnav_stub__"


class HabitatMissing(ImportError):
    """habitat-lab is not importable; the message names the install command."""


def _needs_habitat_sim(name: str):
    """A stand-in class for ``name`` whose use says that habitat-sim is needed."""

    class _Stub:
        def __init__(self, *args, **kwargs):
            raise ImportError(f"{name} needs habitat-sim (with magnum), which is not installed; "
                              "calnav's habitat backend provides only the ObjectNav simulator")

    _Stub.__name__ = _Stub.__qualname__ = name
    return _Stub


def _stub_module(module: str, names: tuple[str, ...]) -> types.ModuleType:
    m = types.ModuleType(module, f"calnav stand-in for {module} (habitat-sim absent)")
    setattr(m, STUB_MARKER, True)
    for name in names:
        if name.startswith("_try_register"):
            setattr(m, name, lambda: None)  # nothing to register without habitat-sim
        else:
            setattr(m, name, _needs_habitat_sim(name))
    return m


def habitat_sim_available() -> bool:
    return importlib.util.find_spec("habitat_sim") is not None


def install_stubs() -> list[str]:
    """Put the stand-ins into ``sys.modules`` (idempotent); returns the stubbed module names.
    Does nothing (returns []) when habitat-sim is installed."""
    if habitat_sim_available():
        return []
    for module, names in STUBBED_MODULES.items():
        if module not in sys.modules:
            sys.modules[module] = _stub_module(module, names)
    return list(STUBBED_MODULES)


def import_habitat() -> types.ModuleType:
    """``import habitat``, with the stand-ins when habitat-sim is absent. Raises
    ``HabitatMissing`` (an ImportError naming the install command) when habitat-lab is absent."""
    if importlib.util.find_spec("habitat") is None:
        raise HabitatMissing(INSTALL_HINT)
    install_stubs()
    import habitat

    return habitat
