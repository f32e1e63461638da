"""Workers die with their driver: a driver killed with SIGKILL leaves no pool worker behind
(the kernel's parent-death signal, eval.backends.die_with_parent); a driver sent SIGINT (alone,
or with its process group as a terminal's Ctrl-C does) stops its workers at once, keeps every
result that finished, and exits."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
HELPER = textwrap.dedent("""
    import os, time
    from pathlib import Path

    def report_and_sleep(out):
        (Path(out) / str(os.getpid())).touch()   # this worker's pid as a file name
        time.sleep(120)
        return os.getpid()
""")
DRIVER = textwrap.dedent("""
    import sys
    from calnav.eval.backends import LocalBackend
    from calnav_orphan_helper import report_and_sleep
    if __name__ == "__main__":   # spawn re-imports this file in each worker
        for _ in LocalBackend(2).map_unordered(report_and_sleep, [sys.argv[1]] * 2):
            pass
""")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as f:   # a zombie has exited
        return f.read().split()[2] != "Z"


def _assert_all_die(pids: list[int], within_s: float = 10.0) -> None:
    """Every worker in ``pids`` is gone within ``within_s`` seconds."""
    deadline = time.monotonic() + within_s
    while any(_alive(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(_alive(p) for p in pids)


def _kill_all(driver, out: Path) -> None:
    """Clean up what a test left: the driver and the workers that wrote their pid to ``out``."""
    driver.kill()
    for p in out.iterdir():
        try:
            os.kill(int(p.name), signal.SIGKILL)
        except ProcessLookupError:
            pass


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="parent-death signals are Linux's")
def test_kill_9_of_the_driver_kills_its_workers(tmp_path):
    out = tmp_path / "pids"
    out.mkdir()
    (tmp_path / "calnav_orphan_helper.py").write_text(HELPER)   # importable by the spawned workers
    (tmp_path / "driver.py").write_text(DRIVER)
    driver = subprocess.Popen([sys.executable, str(tmp_path / "driver.py"), str(out)], cwd=tmp_path,
                              env={**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(REPO)])})
    try:
        deadline = time.monotonic() + 60
        while len(list(out.iterdir())) < 2 and time.monotonic() < deadline:
            time.sleep(0.1)
        pids = [int(p.name) for p in out.iterdir()]
        assert len(pids) == 2 and all(_alive(p) for p in pids)
        driver.send_signal(signal.SIGKILL)
        driver.wait(10)
        _assert_all_die(pids)
    finally:
        _kill_all(driver, out)


SIGINT_DRIVER = textwrap.dedent("""
    import sys
    from types import SimpleNamespace
    from calnav.eval.runner import run_tasks
    from calnav_orphan_helper import first_quick

    def save(task, result):
        with open(sys.argv[2], "a") as f:
            f.write(f"{result}\\n")

    if __name__ == "__main__":   # spawn re-imports this file in each worker
        try:
            run_tasks(first_quick, [(sys.argv[1], i) for i in range(3)],
                      SimpleNamespace(backend="local", ray_address="", workers=2), save=save, desc="t",
                      unit="task", progress=False)
        except KeyboardInterrupt:
            sys.exit(130)
""")
FIRST_QUICK = textwrap.dedent("""

    def first_quick(task):
        out, i = task
        (Path(out) / str(os.getpid())).touch()
        if i:
            time.sleep(120)
        return i
""")
STOP_BOUND_S = 10.0   # SIGINT to the driver's exit (it used to wait for every task still queued)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="parent-death signals are Linux's")
@pytest.mark.parametrize("target", ["driver", "process group"])   # kill -INT PID / a terminal's Ctrl-C
def test_sigint_stops_the_pool_at_once_and_keeps_the_finished(tmp_path, target):
    out, saved = tmp_path / "pids", tmp_path / "saved.txt"
    out.mkdir()
    (tmp_path / "calnav_orphan_helper.py").write_text(HELPER + FIRST_QUICK)
    (tmp_path / "driver.py").write_text(SIGINT_DRIVER)
    driver = subprocess.Popen([sys.executable, str(tmp_path / "driver.py"), str(out), str(saved)], cwd=tmp_path,
                              env={**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(REPO)])},
                              start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while not (saved.exists() and len(list(out.iterdir())) == 2) and time.monotonic() < deadline:
            time.sleep(0.1)
        pids = [int(p.name) for p in out.iterdir()]
        assert saved.read_text() == "0\n" and len(pids) == 2
        t0 = time.monotonic()
        if target == "driver":
            driver.send_signal(signal.SIGINT)
        else:
            os.killpg(driver.pid, signal.SIGINT)
        assert driver.wait(STOP_BOUND_S) == 130 and time.monotonic() - t0 < STOP_BOUND_S
        assert saved.read_text() == "0\n"
        _assert_all_die(pids)
    finally:
        _kill_all(driver, out)
