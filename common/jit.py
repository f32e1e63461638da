"""numba compilation with an on-disk cache, falling back to none where nothing is writable."""
from __future__ import annotations

import numba


def compiled(fn):
    """``numba.njit`` with the machine code cached on disk (beside the module, else in the
    user's cache; seconds of compiling saved per process). Where neither is writable (a
    read-only install and home), numba refuses to cache at all: compile in each process then."""
    try:
        return numba.njit(cache=True, nogil=True)(fn)
    except RuntimeError:
        return numba.njit(nogil=True)(fn)
