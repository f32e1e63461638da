"""Workers die with their driver: a driver killed with SIGKILL leaves no pool worker behind
(the kernel's parent-death signal, eval.backends.die_with_parent)."""
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
        deadline = time.monotonic() + 10
        while any(_alive(p) for p in pids) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(_alive(p) for p in pids)
    finally:
        driver.kill()
        for p in out.iterdir():
            try:
                os.kill(int(p.name), signal.SIGKILL)
            except ProcessLookupError:
                pass
