"""A two-node Ray cluster on this machine (`ray start --head` plus a second `ray start
--address=...`, one CPU each): an evaluation joined with run.ray_address runs episodes on both
nodes. `ray stop --force` at the end stops every Ray process on the machine: run this module
on its own machine or CI, never beside a Ray cluster you use."""
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.e2e

REPO = Path(__file__).resolve().parents[1]
SMALL = ["env.resolution=64x48", "env.dataset.val_scenes=2", "env.dataset.episodes_per_scene=3"]
STARTUP_TIMEOUT_S = 120


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_two_node_ray_cluster_runs_episodes_on_both_nodes(tmp_path):
    pytest.importorskip("ray", reason="the ray extra is installed by `make test`")
    ray_bin = str(Path(sys.executable).with_name("ray"))
    port = _free_port()
    address = f"127.0.0.1:{port}"
    # one auth mode for head, worker node and driver (Ray 2.5x turns token auth on for some starts only)
    env = {**os.environ, "PYTHONPATH": str(REPO), "RAY_USAGE_STATS_ENABLED": "0", "RAY_AUTH_MODE": "disabled"}
    try:
        head = subprocess.run([ray_bin, "start", "--head", f"--port={port}", "--num-cpus=1",
                               "--include-dashboard=false", "--disable-usage-stats"],
                              env=env, capture_output=True, text=True, timeout=STARTUP_TIMEOUT_S)
        assert head.returncode == 0, head.stderr[-2000:]
        worker = subprocess.run([ray_bin, "start", f"--address={address}", "--num-cpus=1"],
                                env=env, capture_output=True, text=True, timeout=STARTUP_TIMEOUT_S)
        assert worker.returncode == 0, worker.stderr[-2000:]
        out = tmp_path / "cluster"
        cmd = [sys.executable, "-c", "import sys; from eval.cli import main; sys.exit(main(sys.argv[1:]))",
               "objectnav", "--agent", "oracle", "--episodes", "0:6", "--output", str(out), *SMALL,
               "run.backend=ray", f"run.ray_address={address}"]
        run = subprocess.run(cmd, env=env, cwd=REPO, capture_output=True, text=True, timeout=600)
        assert run.returncode == 0, run.stderr[-2000:]
        records = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
        assert sorted(r["index"] for r in records) == list(range(6))   # every episode exactly once
        assert len({r["ray_node"] for r in records}) == 2               # both nodes ran episodes
    finally:
        subprocess.run([ray_bin, "stop", "--force"], env=env, capture_output=True, timeout=STARTUP_TIMEOUT_S)
