"""The agent's discrete motion, shared by every simulator front end (the gymnasium env and
habitat-lab's ``CalnavSim-v0``), so both move the agent with the same arithmetic, bit for bit.

Pose: position (2,) float64 world xy, metres; yaw radians counter-clockwise from +x, kept in
[0, 2 pi); pitch radians, positive looks up, clamped to [-MAX_PITCH_RAD, MAX_PITCH_RAD].
"""
from __future__ import annotations

import math

import numpy as np

from calnav.envs.task import Action

MAX_PITCH_RAD = math.radians(90)  # the camera tilts at most straight up / down


def tilt(pitch: float, degrees: float) -> float:
    """Pitch (rad) after tilting by ``degrees`` (positive up), clamped to +-MAX_PITCH_RAD."""
    return max(-MAX_PITCH_RAD, min(pitch + math.radians(degrees), MAX_PITCH_RAD))


def apply_action(navgrid, env_cfg, position: np.ndarray, yaw: float, pitch: float,
                 action: Action) -> tuple[np.ndarray, float, float, bool]:
    """One action's effect: (position, yaw, pitch, collided). MOVE_FORWARD goes
    ``env_cfg.forward_step_m`` along the heading when the segment is navigable (Habitat with
    sliding off) and otherwise collides in place; turns add +-``turn_angle_deg``; looks tilt by
    ``tilt_angle_deg``; STOP changes nothing."""
    collided = False
    if action == Action.MOVE_FORWARD:
        position, moved = navgrid.move_forward(position, yaw, env_cfg.forward_step_m)
        collided = not moved
    elif action == Action.TURN_LEFT:
        yaw = (yaw + math.radians(env_cfg.turn_angle_deg)) % (2 * math.pi)
    elif action == Action.TURN_RIGHT:
        yaw = (yaw - math.radians(env_cfg.turn_angle_deg)) % (2 * math.pi)
    elif action == Action.LOOK_UP:
        pitch = tilt(pitch, env_cfg.tilt_angle_deg)
    elif action == Action.LOOK_DOWN:
        pitch = tilt(pitch, -env_cfg.tilt_angle_deg)
    return position, yaw, pitch, collided


def apply_layered_action(navgrid, env_cfg, position: np.ndarray, layer: int, yaw: float, pitch: float,
                         action: Action) -> tuple[np.ndarray, int, float, float, bool]:
    """``apply_action`` on a ``LayeredNavGrid``: (position, layer, yaw, pitch, collided);
    MOVE_FORWARD may change the layer (stairs), every other action is ``apply_action``'s."""
    if action == Action.MOVE_FORWARD:
        position, layer, moved = navgrid.move_forward(position, layer, yaw, env_cfg.forward_step_m)
        return position, layer, yaw, pitch, not moved
    position, yaw, pitch, collided = apply_action(navgrid, env_cfg, position, yaw, pitch, action)
    return position, layer, yaw, pitch, collided
