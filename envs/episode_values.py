"""The numbers of a habitat-lab episode entry, checked as they are read.

``json`` reads ``NaN`` and ``Infinity``, and ``float()`` takes ``"1"`` and ``true``: without these
checks a start at NaN failed deep in the navmesh lookup without naming the file, and a start
rotation of ``[0, 2, 0, 0.5]`` ran as the yaw its direction gives while habitat-sim would set
a non-rotation. Each helper raises ``ValueError`` naming the episode and the key; the
file's reader (``envs.episode_files.read_episode_file``, ``envs.episode_datasets``) puts the
file's name in front.
"""
from __future__ import annotations

import math

QUATERNION_NORM_TOLERANCE = 1e-3   # |norm - 1| allowed of a start rotation (files round to 5 decimals)


def numbers(value, n: int, what: str) -> list[float]:
    """``value`` as ``n`` finite floats; ValueError naming ``what`` when it is not a list of
    ``n`` finite numbers (strings and booleans included)."""
    ok = (isinstance(value, (list, tuple)) and len(value) == n
          and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value))
    if not ok or not all(math.isfinite(v) for v in value):
        raise ValueError(f"{what} must be {n} finite numbers, got {value!r}")
    return [float(v) for v in value]


def distance(value, what: str) -> float:
    """``value`` as a finite number of metres >= 0; ValueError naming ``what`` otherwise (a
    run's records carry the file's ``info.geodesic_distance``: NaN failed the records' write after
    the run had begun, a negative or quoted number was recorded as the episode's distance)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise ValueError(f"{what} must be a finite distance >= 0 metres, got {value!r}")
    return float(value)


def unit_quaternion(value, what: str) -> list[float]:
    """``value`` as a Habitat [x, y, z, w] quaternion of norm 1 (within
    ``QUATERNION_NORM_TOLERANCE``); ValueError naming ``what`` otherwise."""
    q = numbers(value, 4, what)
    norm = math.sqrt(sum(c * c for c in q))
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise ValueError(f"{what} {q} is not a unit quaternion [x, y, z, w] (norm {norm:.4g}); habitat-sim "
                         "would set it as it is: write the normalised rotation")
    return q
