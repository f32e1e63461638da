"""A two-node Ray cluster on this machine (``ray.cluster_utils.Cluster``: a head and a second
node, one CPU each, started by and owned by this test): an evaluation joined with
run.ray_address runs episodes on both nodes. Only the test's own nodes are stopped at the end
(never a machine-wide ``ray stop``), so a Ray cluster the user runs beside ``make test`` survives."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.e2e

REPO = Path(__file__).resolve().parents[2]
SMALL = ["env.resolution=64x48", "env.dataset.val_scenes=2", "env.dataset.episodes_per_scene=3"]


def test_two_node_ray_cluster_runs_episodes_on_both_nodes(tmp_path, monkeypatch):
    pytest.importorskip("ray", reason="the ray extra is installed by `make test`")
    from ray.cluster_utils import Cluster

    # one auth mode for the nodes and the driver (Ray 2.5x turns token auth on for some starts only)
    for key, value in {"RAY_USAGE_STATS_ENABLED": "0", "RAY_AUTH_MODE": "disabled"}.items():
        monkeypatch.setenv(key, value)
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    try:
        cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        out = tmp_path / "cluster"
        env = {**os.environ, "PYTHONPATH": str(REPO)}
        cmd = [sys.executable, "-c", "import sys; from calnav.eval.cli import main; sys.exit(main(sys.argv[1:]))",
               "objectnav", "--agent", "oracle", "--episodes", "0:6", "--output", str(out), *SMALL,
               "run.backend=ray", f"run.ray_address={cluster.address}"]
        run = subprocess.run(cmd, env=env, cwd=REPO, capture_output=True, text=True, timeout=600)
        assert run.returncode == 0, run.stderr[-2000:]
        records = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
        assert sorted(r["index"] for r in records) == list(range(6))   # every episode exactly once
        assert len({r["ray_node"] for r in records}) == 2               # both nodes ran episodes
    finally:
        cluster.shutdown()   # this test's nodes only
