"""Pause Python's cyclic garbage collector while building a large acyclic structure.

Parsing an episode file builds ~10^6 small lists and floats; the collector runs a generation-0
pass every 700 new container objects and, as they survive, ever more full passes over all of
them: measured on the 30 ``val`` episode files (51 MB of JSON), ``json.loads`` took 1.9 s with
the collector and 0.58 s without it. Parsed JSON holds no reference cycles, so nothing is lost
by collecting after the parse instead of during it.
"""
from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def gc_paused() -> Iterator[None]:
    """Disable the cyclic collector inside the block; restore its previous state after (nested
    uses and a collector already disabled by the caller are left as they were)."""
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()
