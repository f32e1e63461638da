"""The experiment kernel's loop: every command's independent work goes through ``run_tasks``.

A command is a configuration of one pattern (``eval.cli.COMMANDS`` registers it):

1. ``configs(args)`` loads every config it runs; the CLI's preflight checks them (files,
   services, devices) before anything is written;
2. ``main(args, configs)`` opens its results directory with ``eval.results_dir.ResultsDir``
   (lock, config check, ``--force``, atomic ``config.yaml``), lists the tasks still to do (what
   the directory already holds is resumed, not redone) and hands them to ``run_tasks``;
3. ``run_tasks`` runs a picklable top-level ``fn(task)`` for each on the ``run.backend``
   backend (``eval.backends``: in-process, a local process pool whose workers die with the
   driver, or Ray), hands each result to the command's ``save(task, result)`` *as it arrives*
   (so a killed run keeps every finished task), shows one progress bar, and returns the tasks
   that raised, with their errors, after every other result is saved;
4. the command summarises what the directory holds (``summary.json``, tables, plots).

    failures = run_tasks(scan_one, tasks, cfg.run, save=rows.append, desc="scanning houses", unit="house")
    raise_failures(failures, "house")

A task that raises in its worker does not stop the others: its exception comes back as a
``TaskFailed`` (type, message, traceback), and ``raise_failures`` turns a non-empty list into one
``ResultsError`` line naming each failed task, after everything else is written, so a rerun of
the same command retries exactly the failed tasks. A command whose failures are results of their
own passes ``failed=``: ObjectNav writes a crashed episode as an error record in
``episodes.jsonl`` (retried on resume, ``eval.objectnav.run``).

Ctrl-C (SIGINT to the driver, or to its whole process group from a terminal) stops every
backend the same way: the tasks in flight are abandoned (pool workers killed, Ray tasks
cancelled), every task that finished before is saved, and ``KeyboardInterrupt`` goes on to the
CLI (exit 130, "rerun the same command to resume"); the rerun does only what is missing. A
``KeyboardInterrupt`` or ``sys.exit()`` raised by a plugin itself is no Ctrl-C: the plugin
boundary (``common.interrupt.user_code``) makes it a failure of its task.
"""
from __future__ import annotations

import traceback
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Iterator

from calnav.common.interrupt import sigint_flag
from calnav.eval.results_dir import ResultsError


@dataclass(frozen=True)
class TaskFailed:
    """What a task that raised returns to the driver instead of its result."""

    error: str        # "ExceptionType: message"
    traceback: str    # the worker's formatted traceback
    refusal: bool = False   # a ValueError (SceneError, ConfigError, ...): bad input, its message one line


@dataclass(frozen=True)
class _Guarded:
    """``fn`` with its exceptions returned as ``TaskFailed`` (a picklable top-level callable, so
    it runs in every backend's workers). KeyboardInterrupt and SystemExit still propagate."""

    fn: Callable[[Any], Any]

    @property
    def __name__(self) -> str:   # Ray names the tasks (and their workers' process titles) by it
        return self.fn.__name__

    def __call__(self, task):
        try:
            return self.fn(task)
        except Exception as exc:   # a failed task must not take the finished ones with it
            return TaskFailed(f"{type(exc).__name__}: {exc}", traceback.format_exc(), isinstance(exc, ValueError))


def run_tasks(fn: Callable[[Any], Any], tasks: Iterable, run_cfg, *, save: Callable[[Any, Any], None],
              desc: str, unit: str, total: int | None = None, progress: bool = True,
              postfix: Callable[[Any], dict] | None = None,
              failed: Callable[[Any, TaskFailed], None] | None = None,
              backend: Any = None) -> list[tuple[Any, TaskFailed]]:
    """Run ``fn(task)`` for every task on ``run_cfg``'s backend (``run.backend`` / ``run.workers``
    / ``run.ray_address``), calling ``save(task, result)`` in the driver as each result arrives
    (completion order). ``total``: the bar's length when some tasks were already done (resumed);
    default ``len(tasks)``. ``postfix(task)``: running figures shown on the bar after each result (``task``: the one that just finished).
    ``failed(task, TaskFailed)``: saves a failure as it arrives (an episode's error record);
    without it failures are collected. Returns ``[(task, TaskFailed)]`` for the tasks that raised
    and were not handed to ``failed`` (empty when all succeeded). ``backend``: an
    ``eval.backends`` backend to run on instead of ``run_cfg``'s (``run_cfg`` is then unused and
    may be None), for workers no ``RunConfig`` describes (``calnav bench`` times one fresh worker
    process pinned to one thread: ``LocalBackend(1, threads=1, in_process=False)``). The only
    place a worker pool is started; a command checks ``run`` first (``eval.backends.check_backend``,
    which the CLI's preflight runs) so a bad backend fails before its directory is written."""
    from tqdm import tqdm

    from calnav.eval.backends import make_backend

    tasks = list(tasks)
    total = len(tasks) if total is None else total
    if total < len(tasks):
        raise ValueError(f"run_tasks: total={total} is less than the {len(tasks)} tasks to run")
    backend = make_backend(run_cfg) if backend is None else backend
    failures: list[tuple[Any, TaskFailed]] = []

    def arrived(task, result, bar) -> None:
        if isinstance(result, TaskFailed) and failed is not None:
            failed(task, result)
        elif isinstance(result, TaskFailed):
            tqdm.write(f"{desc}: a {unit} failed: {result.error}")
            failures.append((task, result))
        else:
            save(task, result)
        if postfix is not None:
            bar.set_postfix(postfix(task))
        bar.update(1)

    # sigint_flag: a real Ctrl-C is told apart from a plugin's own KeyboardInterrupt (common.interrupt)
    with sigint_flag(), tqdm(total=total, initial=total - len(tasks), desc=desc, unit=unit,
                             disable=not progress) as bar:
        results = backend.map_unordered(_Guarded(fn), tasks)
        try:
            for task, result in results:
                arrived(task, result, bar)
        except KeyboardInterrupt:
            # Ctrl-C: the backend stops its workers and hands back what finished meanwhile;
            # each is saved, then the interrupt goes on (the CLI: exit 130, "rerun to resume")
            for task, result in finished_after_interrupt(results):
                arrived(task, result, bar)
            raise
        finally:
            results.close()   # an error while saving stops the workers now, not when collected
    return failures


def finished_after_interrupt(results: Iterator[tuple[Any, Any]]) -> Iterator[tuple[Any, Any]]:
    """The results a backend's ``map_unordered`` generator hands back once interrupted: a
    ``KeyboardInterrupt`` is thrown into it (when the Ctrl-C came while the driver saved a
    result, it is suspended and has not seen it), it stops its workers and yields the tasks
    that finished before they stopped. Nothing when the Ctrl-C came inside it: it has yielded
    those already and ended."""
    try:
        item = results.throw(KeyboardInterrupt())
        while True:
            yield item
            item = next(results)
    except (KeyboardInterrupt, StopIteration):
        return


def raise_failures(failures: list[tuple[Any, TaskFailed]], what: str,
                   name: Callable[[Any], str] = str) -> None:
    """One ``ResultsError`` line for ``failures`` of ``run_tasks`` (nothing when empty): how many
    ``what`` failed, each by ``name(task)`` with its error, and that a rerun retries them."""
    if not failures:
        return
    listed = "; ".join(f"{name(task)}: {f.error}" for task, f in failures[:5])
    more = f" (and {len(failures) - 5} more)" if len(failures) > 5 else ""
    raise ResultsError(f"{len(failures)} {what}(s) failed, the others are saved; rerun the same command to "
                       f"retry them: {listed}{more}")
