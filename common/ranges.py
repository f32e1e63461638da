"""Declared ranges of config keys: one check and one message for every section.

A config dataclass lists its keys' ranges as a module-level ``{key: Range}`` table (each with a
comment saying why its bounds are physically meaningful) and calls ``check_ranges`` from its
``__post_init__``; a value outside is a ``ValueError`` naming the dotted key, the interval with
its unit and the value given, which ``eval.config`` turns into calnav's one-line error::

    env.nav_cell_m must be in [0.005, 0.5] metres, got 1e-09

Every comparison is written so that NaN and inf fail it, and a bool is not a number here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping


@dataclass(frozen=True)
class Range:
    """The interval ``lo`` <(=) value <(=) ``hi`` (closed unless ``lo_open`` / ``hi_open``), in
    ``unit`` (plural words, e.g. "metres", "pixels"; "" for none)."""

    lo: float
    hi: float
    unit: str = ""
    lo_open: bool = False
    hi_open: bool = False

    def contains(self, value: Any) -> bool:
        """Whether ``value`` is a finite number inside the interval."""
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            return False
        above = value > self.lo if self.lo_open else value >= self.lo
        below = value < self.hi if self.hi_open else value <= self.hi
        return above and below

    def text(self) -> str:
        """The interval as written in messages: ``[0.005, 0.5] metres``, ``[1, 10000] episodes``."""
        interval = f"{'(' if self.lo_open else '['}{_number(self.lo)}, {_number(self.hi)}{')' if self.hi_open else ']'}"
        return f"{interval} {self.unit}" if self.unit else interval

    def check(self, key: str, value: Any) -> None:
        """ValueError naming ``key`` unless ``contains(value)``."""
        if not self.contains(value):
            raise ValueError(f"{key} must be in {self.text()}, got {value!r}")


def _number(value: float) -> str:
    """A bound as text: whole numbers without exponent (1000000, not 1e+06), others as %g."""
    return str(int(value)) if float(value).is_integer() else f"{value:g}"


def check_ranges(obj: Any, prefix: str, ranges: Mapping[str, Range]) -> None:
    """``Range.check`` of every attribute of ``obj`` named in ``ranges``, the key written
    ``prefix.name`` (``prefix`` the section's dotted path, e.g. ``env.dataset``)."""
    for name, rng in ranges.items():
        rng.check(f"{prefix}.{name}", getattr(obj, name))
