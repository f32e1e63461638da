"""The ObjectNav task's action interface: the action enum and action-id validation.

Action ids follow habitat-lab's ObjectNav action space order (STOP=0, MOVE_FORWARD=1,
TURN_LEFT=2, TURN_RIGHT=3, LOOK_UP=4, LOOK_DOWN=5); LOOK_UP/DOWN exist only when the
environment is configured with ``enable_look: true``.
"""
from __future__ import annotations

from enum import IntEnum


class Action(IntEnum):
    STOP = 0
    MOVE_FORWARD = 1
    TURN_LEFT = 2
    TURN_RIGHT = 3
    LOOK_UP = 4
    LOOK_DOWN = 5


def num_actions(enable_look: bool) -> int:
    return 6 if enable_look else 4


def check_action(action, enable_look: bool) -> Action:
    """Validate an action id; a clear error lists the valid ids and names."""
    try:
        a = int(action)
    except (TypeError, ValueError):
        a = None
    n = num_actions(enable_look)
    if a is None or not 0 <= a < n or a != action:
        valid = ", ".join(f"{i}={Action(i).name}" for i in range(n))
        raise ValueError(f"invalid action {action!r}; valid actions: {valid}")
    return Action(a)

