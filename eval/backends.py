"""Execution backends: where an experiment's independent work items run (``run.backend``).

A backend maps a picklable top-level function over items and yields ``(item, result)`` pairs
as they finish, in completion order, so the driver can write each result as it arrives:

    backend = make_backend(cfg.run)
    for item, result in backend.map_unordered(fn, items):
        ...

| ``run.backend`` | where items run | workers |
|---|---|---|
| ``local`` | this machine: in-process for 1 worker, else a spawn ``ProcessPoolExecutor`` whose workers die with the driver (kill -9 included) and share the cores (``common.threads``: cores // workers threads each) | ``run.workers`` (0 = all cores) |
| ``ray`` | Ray tasks on a local Ray instance (``run.ray_address: ""``) or a cluster (``auto``, ``ray://host:port``) | the cluster's CPUs; ``run.workers`` > 0 caps the tasks in flight |

On Ctrl-C (a ``KeyboardInterrupt`` in the driver, also thrown into the generator by
``eval.runner.run_tasks`` when it came while a result was being saved) a backend stops its
workers at once (pool workers are killed: they ignore SIGINT themselves; Ray tasks are
cancelled), yields the items that finished before, and re-raises; when the driver stops reading
(closes the generator) its workers stop too.

Functions keep expensive per-process state (an env and an agent) in module-level caches, so a
pool worker or a Ray worker process stays warm across items (Ray reuses worker processes for
tasks of the same function). Ray retries a task whose worker process or node died
(``RAY_TASK_RETRIES``), so a lost node costs only its in-flight items; exceptions inside ``fn``
are not retried (the functions here return error records instead of raising).

Workers on other nodes do not read the driver's cache directory: scenes and episodes are
generated deterministically from their seeds in each node's own ``$CALNAV_CACHE`` (default
``~/.cache/calnav``), so every node sees the same houses. Each node needs calnav installed
(``pip install -e ".[ray]"``), as for any Ray application.
"""
from __future__ import annotations

import multiprocessing as mp
import os
import sys
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Any, Callable, Iterable, Iterator

from calnav.common.registry import Registry

RAY_EXTRA_HINT = 'run.backend=ray needs Ray: pip install -e ".[ray]" (make test installs it into .venv)'
RAY_TASK_RETRIES = 3          # re-runs of a task whose worker process or node died
# Environment the Ray workers need from the driver (Ray does not forward the driver's environment).
FORWARDED_ENV = ("CALNAV_CACHE", "OMP_WAIT_POLICY", "PYTHONPATH")
RAY_CONNECT_TIMEOUT_S = 10.0   # a cluster address that does not answer within this fails before anything is written


def check_backend(name: str, address: str = "") -> None:
    """Raise ValueError naming the choices (or the install command) before anything runs."""
    BACKENDS.check(name)
    if name == "ray":
        try:
            import ray  # noqa: F401
        except ImportError:
            raise ValueError(RAY_EXTRA_HINT) from None
        check_ray_reachable(address)
    elif address:
        raise ValueError(f"run.ray_address={address!r} is only used with run.backend=ray")


def check_ray_reachable(address: str, timeout_s: float = RAY_CONNECT_TIMEOUT_S) -> None:
    """ValueError unless ``host:port`` (or ``ray://host:port``) accepts a TCP connection within
    ``timeout_s``: Ray itself retries an unreachable address for minutes. "" (a local instance)
    and "auto" (Ray's own lookup, which fails at once when no cluster runs) are not probed."""
    import socket

    if address in ("", "auto"):
        return
    hostport = address.removeprefix("ray://")
    host, sep, port = hostport.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"run.ray_address={address!r} is not an address; valid forms: '' (a local Ray), auto, "
                         "host:port, ray://host:port")
    try:
        socket.create_connection((host, int(port)), timeout=timeout_s).close()
    except OSError as exc:
        raise ValueError(f"cannot reach Ray at run.ray_address={address!r} ({exc.strerror or exc}); start the "
                         "cluster (ray start --head) or use run.ray_address='' for a local Ray") from None


PR_SET_PDEATHSIG = 1   # prctl(2) option: the signal a process gets when its parent dies (Linux)


def init_worker(threads: int) -> None:
    """Pool-worker initializer: die with the driver, leave Ctrl-C to it, and use ``threads``
    threads in every threading library (``common.threads``; before anything imports Open3D or
    torch here), so N workers share the cores instead of each starting one thread per core."""
    import signal

    from calnav.common.threads import pin_threads

    die_with_parent()
    # A terminal sends SIGINT to the whole process group: the driver alone decides what it
    # means (it stops the pool and saves what finished, LocalBackend.map_unordered); in a
    # worker it would end a task half-way or the worker itself, and break the pool.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    pin_threads(threads)


def die_with_parent() -> None:
    """Pool-worker initializer: on Linux, ask the kernel to SIGKILL this process when its
    parent (the driver) dies, even by kill -9, so no worker outlives its run. Elsewhere a
    no-op (the pool's own shutdown still stops workers on a normal exit)."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes
    import signal

    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    except OSError:
        pass   # no libc.so.6 (an unusual Linux): workers then stop only with a normal shutdown
    if os.getppid() == 1:   # the driver died before the request took effect
        os._exit(1)


def kill_workers(pool: ProcessPoolExecutor) -> None:
    """SIGKILL the worker processes of ``pool`` (their tasks in flight are lost; the pool then
    marks its pending futures broken, so its shutdown returns at once instead of waiting for
    them). ``ProcessPoolExecutor`` has no public way to do it before Python 3.14."""
    kill = getattr(pool, "kill_workers", None)   # Python >= 3.14
    if kill is not None:
        kill()
        return
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        try:
            process.kill()
        except (OSError, ValueError):   # already gone, or closed
            pass


def finished_ok(future) -> bool:
    """Whether ``future`` finished with a result (not cancelled, no exception), without waiting."""
    return future.done() and not future.cancelled() and future.exception() is None


class LocalBackend:
    """This machine's cores: in-process for one worker, a spawn process pool otherwise
    (Open3D's thread pools do not survive fork())."""

    def __init__(self, workers: int = 0, threads: int = 0, in_process: bool = True):
        """workers: worker processes (0 = all cores; never more than items); threads: threads
        per worker process (``common.threads``; 0 = cores // workers); in_process: one worker
        runs in this process. ``in_process=False`` runs even one worker in a fresh spawned
        process pinned to ``threads`` -- what ``calnav bench`` measures a study's worker on."""
        if threads < 0:
            raise ValueError(f"LocalBackend: threads must be >= 0 (0 = cores // workers), got {threads}")
        self.workers = workers or os.cpu_count() or 1
        self.threads, self.in_process = threads, in_process

    def map_unordered(self, fn: Callable[[Any], Any], items: Iterable) -> Iterator[tuple[Any, Any]]:
        items = list(items)
        workers = max(1, min(self.workers, len(items)))
        if not items:
            return
        if workers == 1 and self.in_process:
            for item in items:
                yield item, fn(item)
            return
        threads = self.threads or max(1, (os.cpu_count() or 1) // workers)
        pool = ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=init_worker,
                                   initargs=(threads,))
        pending: dict = {}
        completed = False
        try:
            pending.update({pool.submit(fn, item): item for item in items})
            try:
                while pending:
                    done, _ = wait(pending, return_when=FIRST_COMPLETED)
                    for fut in done:
                        yield pending.pop(fut), fut.result()
            except KeyboardInterrupt:
                # Ctrl-C, here or thrown in by the driver while it saved a result
                # (eval.runner.run_tasks): stop the workers now, then hand back the results
                # that finished before they stopped, so that every finished task is saved
                kill_workers(pool)
                for fut in [f for f in pending if finished_ok(f)]:
                    yield pending.pop(fut), fut.result()
                raise
            completed = True
        finally:
            # interrupted, or the driver stopped reading (an error while it saved a result): its
            # workers go now, without finishing the tasks in flight, whose results nobody reads
            if not completed:
                kill_workers(pool)
            pool.shutdown(wait=True, cancel_futures=True)


class RayBackend:
    """Ray tasks; joins ``address`` ("" = start a local instance, "auto", "ray://host:port")."""

    def __init__(self, address: str = "", workers: int = 0):
        check_backend("ray")
        self.address, self.workers = address, workers

    def _init(self):
        import ray

        if not ray.is_initialized():
            env = {k: os.environ[k] for k in FORWARDED_ENV if k in os.environ}
            ray.init(address=self.address or None, runtime_env={"env_vars": env} if env else None,
                     include_dashboard=False, log_to_driver=False, configure_logging=False)
        return ray

    def map_unordered(self, fn: Callable[[Any], Any], items: Iterable) -> Iterator[tuple[Any, Any]]:
        items = list(items)
        if not items:
            return
        ray = self._init()
        # one remote function for every fn (a callable object too: ray.remote takes functions only)
        remote = ray.remote(max_retries=RAY_TASK_RETRIES, retry_exceptions=False)(_apply).options(
            name=getattr(fn, "__name__", "task"))   # the task's (and its worker's ray::NAME) name: fn's
        cap = self.workers if self.workers > 0 else len(items)
        queue = list(reversed(items))
        pending: dict = {}
        try:
            while queue or pending:
                while queue and len(pending) < cap:
                    item = queue.pop()
                    pending[remote.remote(fn, item)] = item
                done, _ = ray.wait(list(pending), num_returns=1)
                for ref in done:
                    yield pending.pop(ref), ray.get(ref)
        except KeyboardInterrupt:   # as LocalBackend: hand back what finished, the rest is cancelled below
            ready, _ = ray.wait(list(pending), num_returns=len(pending), timeout=0) if pending else ([], [])
            for ref in ready:
                yield pending.pop(ref), ray.get(ref)
            raise
        finally:
            for ref in pending:   # interrupted, or the driver stopped reading: the tasks in flight go now
                try:
                    ray.cancel(ref, force=True)
                except Exception:  # noqa: BLE001 -- best effort: Ray ends a dead driver's tasks itself
                    pass


def _apply(fn: Callable[[Any], Any], item: Any) -> Any:
    """A Ray task's body: ``fn(item)`` on the one CPU the task asked for (``common.threads``;
    Ray sets OpenMP's variable itself, the rest is set here)."""
    from calnav.common.threads import ENV, pin_threads

    if os.environ.get(ENV) != "1":
        pin_threads(1)
    return fn(item)


def ray_node_id() -> str | None:
    """The id of the Ray node this process runs on, or None outside a Ray worker (no import:
    only a process that already runs Ray has it loaded)."""
    ray = sys.modules.get("ray")
    if ray is None or not ray.is_initialized():
        return None
    return ray.get_runtime_context().get_node_id()


# run.backend -> the backend's constructor from a ``RunConfig`` (``eval.config.RunConfig`` checks
# its ``backend`` against these names; this module imports nothing heavy at its top)
BACKENDS: Registry[Callable[[Any], "LocalBackend | RayBackend"]] = Registry("backend", key="run.backend")


@BACKENDS.register("local", "this machine's cores: in-process for 1 worker, else a spawn process pool")
def local_backend(run) -> LocalBackend:
    return LocalBackend(run.workers)


@BACKENDS.register("ray", "Ray tasks on a local instance or a cluster (run.ray_address)")
def ray_backend(run) -> RayBackend:
    return RayBackend(run.ray_address, run.workers)


def make_backend(run_cfg) -> LocalBackend | RayBackend:
    """The backend of a ``RunConfig`` (``backend``, ``ray_address``, ``workers``); raises
    ValueError naming the choices, or the install command, before anything runs."""
    check_backend(run_cfg.backend, run_cfg.ray_address)
    return BACKENDS.get(run_cfg.backend)(run_cfg)
