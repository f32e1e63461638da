"""Threads per process: how many cores one worker may use.

A run with ``run.workers`` = N on a C-core machine gives each worker ``max(1, C // N)`` threads
(``eval.backends``); a Ray task gets one (the one CPU it asks for). Every library that
threads is told the same budget, so N workers never run N x C threads on C cores: OpenMP
(Open3D's voxel-grid kernels, torch's default), BLAS, torch (``torch.set_num_threads``) and
calnav's renderer (``envs.render.Renderer``'s ray casting and post-processing), which reads
``thread_budget()``. OpenMP and BLAS read their variables once, when the library loads, so
``pin_threads`` must run before Open3D or torch is imported in that process: a spawned pool
worker's initializer does (its start-up imports ``eval.cli``, which loads numpy -- whose BLAS
then keeps its default -- but neither Open3D nor torch); for torch already running it also calls
``torch.set_num_threads``.
"""
from __future__ import annotations

import os
import sys
from contextlib import contextmanager

ENV = "CALNAV_THREADS"   # the budget, read by thread_budget(); unset = all cores
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS")


def thread_budget() -> int:
    """Threads this process may use: ``$CALNAV_THREADS`` when set (a worker), else all cores."""
    value = os.environ.get(ENV, "")
    return int(value) if value.isdigit() and int(value) > 0 else (os.cpu_count() or 1)


def pin_threads(n: int) -> None:
    """Give this process ``n`` >= 1 threads in every threading library (see the module docstring)."""
    if n < 1:
        raise ValueError(f"threads must be >= 1, got {n}")
    os.environ[ENV] = str(n)
    for var in THREAD_VARS:
        os.environ[var] = str(n)
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(n)


@contextmanager
def single_threaded_torch():
    """Run torch ops on one thread. The per-frame tensors are small (~10^5 elements) and
    torch's OpenMP workers, spinning after each parallel op, starve Open3D's TBB workers:
    on 2 cores that turned a 20 ms frame into 200 ms. (torch is imported here, not at the top:
    this module must be importable before torch, see ``pin_threads``.)"""
    import torch

    old = torch.get_num_threads()
    if old != 1:
        torch.set_num_threads(1)
    try:
        yield
    finally:
        if old != 1:
            torch.set_num_threads(old)
