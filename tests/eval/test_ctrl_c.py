"""Ctrl-C of `calnav objectnav` with 2 workers: the run stops within seconds (the episodes in
flight are abandoned), exits 130 saying how to resume, keeps every finished episode's record,
and the rerun of the same command completes the rest, each episode once."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
EPISODES = 5
SMALL = ["env.resolution=64x48", "env.dataset.val_scenes=1", f"env.dataset.episodes_per_scene={EPISODES}",
         "env.max_episode_steps=100", "run.workers=2", "agent.segmenter=tests.agent.segmenter_plugins:slow"]
SLOW_S = "0.1"            # seconds per frame of the slow plugin: an episode takes ~10 s (100 frames)
FIRST_RECORD_S = 300.0    # bound on the wait for the first finished episode (2 busy cores)
STOP_BOUND_S = 10.0       # SIGINT to exit; the unfinished episodes take ~20 s more on 2 workers
RESUME = "calnav objectnav: interrupted; finished work is kept: rerun the same command to resume"


def _calnav(out: Path, slow_s: str, **popen) -> subprocess.Popen:
    env = {**os.environ, "CALNAV_TEST_SLOW_SEGMENTER_S": slow_s,   # not in the config: the rerun resumes
           "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}
    return subprocess.Popen([sys.executable, "-m", "calnav", "objectnav", "--episodes", f"0:{EPISODES}",
                             "--output", str(out), *SMALL], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **popen)


@pytest.mark.e2e
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="process groups and signals as on Linux")
def test_ctrl_c_with_two_workers_stops_keeps_and_resumes(tmp_path, monkeypatch):
    out = tmp_path / "run"
    records = out / "episodes.jsonl"
    run = _calnav(out, SLOW_S, start_new_session=True)   # its own process group, as a terminal's job
    try:
        deadline = time.monotonic() + FIRST_RECORD_S
        while not (records.exists() and records.read_text().endswith("\n")) and time.monotonic() < deadline:
            assert run.poll() is None, run.communicate()
            time.sleep(0.1)
        t0 = time.monotonic()
        os.killpg(run.pid, signal.SIGINT)   # what Ctrl-C in a terminal does: driver and workers get it
        _, err = run.communicate(timeout=STOP_BOUND_S)
        stopped_s = time.monotonic() - t0
    finally:
        run.kill()
    assert run.returncode == 130 and stopped_s < STOP_BOUND_S, (run.returncode, stopped_s, err)
    assert err.rstrip().splitlines()[-1] == RESUME
    kept = records.read_text()
    before = [json.loads(line) for line in kept.splitlines()]
    assert 1 <= len(before) < EPISODES and all(r["status"] == "ok" for r in before)

    # the same command again, here in this process (the interrupted run above is the real
    # process and its process group; resuming reads only what it left), its model not slowed
    import tests.agent.segmenter_plugins as plugins
    from calnav.eval.cli import main

    monkeypatch.setenv("CALNAV_TEST_SLOW_SEGMENTER_S", "0")   # the pool's workers import the plugin afresh
    monkeypatch.setattr(plugins, "SLOW_S", 0.0)               # a last episode left runs in this process
    assert main(["objectnav", "--episodes", f"0:{EPISODES}", "--output", str(out), *SMALL]) == 0
    after = records.read_text()
    assert after.startswith(kept)   # the records kept are left as they were
    indices = [json.loads(line)["index"] for line in after.splitlines()]
    assert sorted(indices) == list(range(EPISODES))   # every episode, once
