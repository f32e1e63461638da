"""The experiment kernel's loop (eval.runner): every result is saved as it arrives, a task that
raises does not take the others with it (in-process, in a process pool and on Ray), and the
failures come back as one line naming each task after the rest is saved."""
import os
from pathlib import Path
from types import SimpleNamespace

import pytest

from calnav.eval.results_dir import ResultsError
from calnav.eval.runner import TaskFailed, raise_failures, run_tasks


def square_unless_three(x: int) -> int:
    if x == 3:
        raise ValueError(f"task {x} is broken")
    return x * x


def _run(cfg, **kw):
    saved = {}
    failures = run_tasks(square_unless_three, [1, 2, 3, 4], cfg, save=saved.__setitem__, desc="t", unit="task",
                         progress=False, **kw)
    return saved, failures


@pytest.mark.parametrize("workers", [1, 2])
def test_a_failing_task_leaves_the_others_saved(workers):
    saved, failures = _run(SimpleNamespace(backend="local", ray_address="", workers=workers))
    assert saved == {1: 1, 2: 4, 4: 16}
    assert [t for t, _ in failures] == [3]
    f = failures[0][1]
    assert isinstance(f, TaskFailed) and f.error == "ValueError: task 3 is broken"
    assert "square_unless_three" in f.traceback
    with pytest.raises(ResultsError) as exc:
        raise_failures(failures, "house", name=lambda t: f"house {t}")
    assert str(exc.value) == ("1 house(s) failed, the others are saved; rerun the same command to retry them: "
                              "house 3: ValueError: task 3 is broken")
    raise_failures([], "house")   # nothing failed: nothing raised


def test_failures_handed_to_failed_are_saved_not_returned():
    got = []
    saved, failures = _run(SimpleNamespace(backend="local", ray_address="", workers=1),
                           failed=lambda t, f: got.append((t, f.error)))
    assert failures == [] and got == [(3, "ValueError: task 3 is broken")] and len(saved) == 3


def test_progress_total_and_postfix():
    seen = []
    run_tasks(square_unless_three, [1, 2], SimpleNamespace(backend="local", ray_address="", workers=1),
              save=lambda t, r: None, desc="t", unit="task", total=5, progress=False,
              postfix=lambda t: seen.append(t) or {})
    assert seen == [1, 2]   # called with the task that just finished
    with pytest.raises(ValueError, match="total=1 is less than the 2 tasks"):
        run_tasks(square_unless_three, [1, 2], SimpleNamespace(backend="local", ray_address="", workers=1),
                  save=lambda t, r: None, desc="t", unit="task", total=1, progress=False)


def test_a_failing_task_on_ray_leaves_the_others_saved(local_ray):
    saved, failures = _run(SimpleNamespace(backend="ray", ray_address="", workers=0))
    assert saved == {1: 1, 2: 4, 4: 16}
    assert [(t, f.error) for t, f in failures] == [(3, "ValueError: task 3 is broken")]


def thread_settings(_) -> tuple[str, str, int]:
    from calnav.common.threads import thread_budget

    return os.environ.get("CALNAV_THREADS", ""), os.environ.get("OMP_NUM_THREADS", ""), thread_budget()


def test_pool_workers_share_the_cores():
    """N local workers get cores // N threads each in every threading library (they used to
    start one thread per core each: N x cores threads on the machine)."""
    from calnav.eval.backends import LocalBackend

    cores = os.cpu_count() or 1
    got = {r for _, r in LocalBackend(2).map_unordered(thread_settings, [0, 1])}
    share = max(1, cores // 2)
    assert got == {(str(share), str(share), share)}


def settings_and_pid(_) -> tuple[tuple[str, str, int], int]:
    return thread_settings(_), os.getpid()


def test_a_given_backend_runs_one_task_in_a_fresh_pinned_worker():
    """``run_tasks(..., backend=LocalBackend(1, threads=1, in_process=False))`` (what ``calnav
    bench`` times a study's worker on): the one task runs in another process, on one thread,
    and its failures come back as for every run; without ``in_process=False`` one worker is
    this process, with its own thread budget."""
    from calnav.eval.backends import LocalBackend

    saved: dict = {}
    fresh = LocalBackend(1, threads=1, in_process=False)
    assert run_tasks(settings_and_pid, [0], None, save=saved.__setitem__, desc="t", unit="task", progress=False,
                     backend=fresh) == []
    (threads, pid), = saved.values()
    assert pid != os.getpid() and threads == ("1", "1", 1)
    in_process = dict(LocalBackend(1, threads=1).map_unordered(settings_and_pid, [0]))
    assert in_process[0][1] == os.getpid()
    failures = run_tasks(square_unless_three, [3], None, save=saved.__setitem__, desc="t", unit="task",
                         progress=False, backend=fresh)
    assert [(t, f.error) for t, f in failures] == [(3, "ValueError: task 3 is broken")]
    with pytest.raises(ValueError, match="threads must be >= 0"):
        LocalBackend(1, threads=-1)


SLOW_TASK_S = 120.0     # a task still in flight at Ctrl-C: waiting for it would fail the time bound
STOP_BOUND_S = 30.0     # Ctrl-C to KeyboardInterrupt out of run_tasks, pool shut down (2 busy cores)


def quick_then_slow(task: tuple[int, str]) -> int:
    """Task 0 returns at once, task 1 after leaving ``<dir>/1`` behind, the others run for
    SLOW_TASK_S (still in flight when the driver is interrupted)."""
    import time

    i, folder = task
    if i == 1:
        (Path(folder) / "1").touch()
    elif i > 1:
        time.sleep(SLOW_TASK_S)
    return i


def test_ctrl_c_while_saving_keeps_the_results_finished_meanwhile(tmp_path):
    """A Ctrl-C that reaches the driver while it saves one result (not while it waits for the
    pool): the workers stop at once, and a task that finished meanwhile is saved too."""
    import time

    saved: dict = {}

    def save(task, result):
        saved[task[0]] = result
        if len(saved) == 1:   # task 0: wait until task 1 has finished in its worker, then Ctrl-C
            deadline = time.monotonic() + STOP_BOUND_S
            while not (tmp_path / "1").exists() and time.monotonic() < deadline:
                time.sleep(0.05)
            time.sleep(1.0)   # its result reaches the driver's pool thread
            raise KeyboardInterrupt

    t0 = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        run_tasks(quick_then_slow, [(i, str(tmp_path)) for i in range(4)],
                  SimpleNamespace(backend="local", ray_address="", workers=2), save=save, desc="t", unit="task",
                  progress=False)
    assert time.monotonic() - t0 < STOP_BOUND_S
    assert saved == {0: 0, 1: 1}
