"""Execution backends (eval.backends): the local pool and Ray give the same per-episode records,
a multirun fans all its configurations out at once, a killed Ray worker or driver costs only
in-flight episodes, and a two-node Ray cluster runs episodes on both nodes."""
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

import calnav.eval.backends as backends
from calnav.eval.backends import BACKENDS, LocalBackend, check_backend
from calnav.eval.cli import main
from calnav.eval.config import RunConfig, load_config
from calnav.eval.objectnav.run import EpisodeJob, run_jobs


SMALL = ["env.resolution=64x48", "env.dataset.val_scenes=2", "env.dataset.episodes_per_scene=3"]
PEANUT_GT = ["agent.segmenter=gt", "agent.map_resolution=64x48", "env.max_episode_steps=60"]
REPO = Path(__file__).resolve().parents[2]
METRICS = ("success", "spl", "softspl", "distance_to_goal", "steps", "path_length", "collisions", "stop_reason")


def load_records(path) -> list[dict]:
    """Every valid record line of a records file, duplicates included (so "exactly once" is
    checked on the file itself, not on read_records' de-duplicated view)."""
    out = []
    for line in Path(path).read_text().splitlines():
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            continue  # a torn line of a killed driver
        if isinstance(rec, dict) and "index" in rec:
            out.append(rec)
    return out


def _metrics(records: list[dict]) -> dict[int, tuple]:
    return {r["index"]: tuple(r[k] for k in METRICS) for r in records}


def test_backends_are_chosen_from_their_registry(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # RayBackend's constructor checks the import: no Ray needed
    assert isinstance(BACKENDS.get("local")(RunConfig(workers=3)), LocalBackend)
    assert BACKENDS.get("local")(RunConfig(workers=3)).workers == 3
    with pytest.raises(ValueError, match=r'pip install -e "\.\[ray\]"'):   # the ray entry builds a RayBackend
        BACKENDS.get("ray")(RunConfig(backend="ray"))
    with pytest.raises(ValueError, match="^unknown backend 'slurm' for run.backend; valid choices: local, ray$"):
        check_backend("slurm")
    with pytest.raises(ValueError, match="only used with run.backend=ray"):
        check_backend("local", "auto")


def test_missing_ray_names_the_install_command(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    with pytest.raises(ValueError, match=r'pip install -e "\.\[ray\]"'):
        check_backend("ray")


def test_unreachable_ray_address_fails_before_writing(tmp_path, capsys):
    """An unreachable run.ray_address=127.0.0.1:1 fails before the results directory is written (no retrying for ever)."""
    pytest.importorskip("ray", reason="the ray extra is installed by `make test`")
    import time

    from calnav.eval.cli import main

    out = tmp_path / "run"
    t0 = time.monotonic()
    rc = main(["objectnav", "--agent", "oracle", "--episodes", "0:1", "--output", str(out), *SMALL,
               "run.backend=ray", "run.ray_address=127.0.0.1:1"])
    assert rc == 2 and not out.exists() and time.monotonic() - t0 < 60
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot reach Ray at run.ray_address='127.0.0.1:1'" in err[0]
    with pytest.raises(ValueError, match="valid forms: '' \\(a local Ray\\), auto, host:port"):
        check_backend("ray", "my-cluster")


def test_local_and_ray_map_the_same_results(local_ray):
    from calnav.eval.backends import RayBackend

    from calnav.envs.semantics import CLASS_NAMES, class_id   # a plain function importable on every worker

    local = dict(LocalBackend(workers=2).map_unordered(class_id, CLASS_NAMES))
    remote = dict(RayBackend(workers=2).map_unordered(class_id, CLASS_NAMES))
    assert local == remote == {name: i for i, name in enumerate(CLASS_NAMES)}


def test_ray_objectnav_matches_the_local_pool_per_episode(local_ray, tmp_path):
    def cmd(out, *extra):
        return ["objectnav", "--episodes", "0:4", "--output", str(tmp_path / out), *SMALL, *PEANUT_GT, *extra]

    assert main(cmd("local", "run.workers=2")) == 0
    assert main(cmd("ray", "run.backend=ray")) == 0
    local = load_records(tmp_path / "local" / "episodes.jsonl")
    remote = load_records(tmp_path / "ray" / "episodes.jsonl")
    assert _metrics(local) == _metrics(remote) and len(remote) == 4
    assert all("ray_node" in r for r in remote)          # where each episode ran is recorded
    # the backend is not a result: the local directory resumes (nothing to do) under ray
    assert main(cmd("local", "run.backend=ray")) == 0
    assert len(load_records(tmp_path / "local" / "episodes.jsonl")) == 4


def test_multirun_submits_every_configuration_at_once(tmp_path, monkeypatch):
    calls = []

    class Recording(LocalBackend):
        def map_unordered(self, fn, items):
            items = list(items)
            calls.append(sorted({(t.job, t.index) for t in items}))
            yield from super().map_unordered(fn, items)

    monkeypatch.setattr(backends, "make_backend", lambda run: Recording(1))
    jobs = [EpisodeJob(load_config(None, [*SMALL, "run.agent=oracle", f"env.max_episode_steps={n}"]), [0, 1],
                       tmp_path / str(n)) for n in (200, 300)]
    summaries = run_jobs(jobs, progress=False, plots=False)
    assert calls == [[(0, 0), (0, 1), (1, 0), (1, 1)]]   # one batch holding both configurations
    assert [s["count"] for s in summaries] == [2, 2]
    assert all(len(load_records(j.out / "episodes.jsonl")) == 2 for j in jobs)


def _ray_worker_pids() -> set[int]:
    out = subprocess.run(["ps", "-eo", "pid,args"], capture_output=True, text=True).stdout
    return {int(line.split()[0]) for line in out.splitlines()[1:] if "ray::run_episode_task" in line}


N_KILL = 6   # episodes of the killed-worker run (all of SMALL's 2 val houses x 3)


def test_a_killed_ray_worker_costs_only_its_episode(local_ray, tmp_path):
    out = tmp_path / "killed"
    cfg = load_config(None, [*SMALL, *PEANUT_GT, "run.backend=ray"])
    done = threading.Event()
    result = {}

    def run():
        result["summary"] = run_jobs([EpisodeJob(cfg, list(range(N_KILL)), out)], progress=False, plots=False)[0]
        done.set()

    t = threading.Thread(target=run)
    t.start()
    killed = None
    deadline = time.time() + 120
    while not done.is_set() and time.time() < deadline and killed is None:
        pids = _ray_worker_pids()
        if pids:
            killed = min(pids)
            os.kill(killed, signal.SIGKILL)   # a worker lost mid-episode
        time.sleep(0.05)
    t.join(timeout=300)
    assert killed is not None, "no busy Ray worker seen to kill"
    assert done.is_set(), "the run did not finish after the worker was killed"
    records = load_records(out / "episodes.jsonl")
    assert sorted(r["index"] for r in records) == list(range(N_KILL))      # every episode exactly once
    assert all(r["status"] == "ok" for r in records) and result["summary"]["count"] == N_KILL


def test_a_killed_ray_driver_resumes_without_duplicates(local_ray, tmp_path):
    """The driver -- a real process, with the Ray instance it started -- killed with -9 after two
    records; the same command resumes (here in this process, on the session's Ray instance: the
    resume reads the records the killed driver left, whichever Ray runs the rest)."""
    out = tmp_path / "driver"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    args = ["objectnav", "--agent", "oracle", "--episodes", "0:6", "--output", str(out), *SMALL,
            "run.backend=ray", "run.workers=1"]
    cmd = [sys.executable, "-c", "import sys; from calnav.eval.cli import main; sys.exit(main(sys.argv[1:]))", *args]
    proc = subprocess.Popen(cmd, env=env, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    path = out / "episodes.jsonl"
    deadline = time.time() + 180
    while time.time() < deadline and not (path.exists() and path.read_text().count("\n") >= 2):
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)   # the driver (and the Ray instance it started) die
    proc.wait()
    first = len(load_records(path))
    assert 2 <= first < 6
    assert main(args) == 0
    records = load_records(path)
    assert sorted(r["index"] for r in records) == list(range(6))


def test_calibration_houses_recorded_on_ray_match_local_bytes(local_ray, tmp_path):
    """calibrate-map's slow stage as Ray tasks: the files the driver writes from the workers'
    bytes hold the same arrays as the local backend's (npz bytes differ only by zip times)."""
    import numpy as np

    from calnav.eval.config import CALIBRATION_SECTIONS
    from calnav.eval.calibration.record import record_houses, scene_files

    tiny = ["study.segmenters=[learned_rgb]", "study.calib_train_scenes=1", "study.calib_val_scenes=1",
            "study.test_scenes=1", "scan.frames=12"]
    houses = {"house_test_0000": 12}
    files = {}
    for backend in ("local", "ray"):
        cfg = load_config(None, [*tiny, f"run.backend={backend}", "run.workers=2"], sections=CALIBRATION_SECTIONS)
        record_houses(cfg, houses, ("learned_rgb",), tmp_path / backend, progress=False)
        files[backend] = [dict(np.load(p)) for sid in houses
                          for p in scene_files(tmp_path / backend, "learned_rgb", sid)]
    assert len(files["local"]) == len(files["ray"]) == 2
    for a, b in zip(files["local"], files["ray"]):
        assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


def test_ray_backend_without_ray_fails_before_anything_is_written(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    out = tmp_path / "r"
    assert main(["objectnav", "--agent", "oracle", "--episodes", "0:1", "--output", str(out), *SMALL,
                 "run.backend=ray"]) == 2
    assert 'pip install -e ".[ray]"' in capsys.readouterr().err
    assert not out.exists()


def test_the_pool_is_fed_longest_episodes_first_within_each_house():
    """Houses stay together (a worker keeps its house loaded) and each house's longest episodes go
    first, so a run ends on its shortest episodes instead of leaving a core idle on a long one."""
    from calnav.envs.episodes import load_split
    from calnav.eval.config import agent_setup
    from calnav.eval.objectnav.run import EpisodeTask, feed_order

    cfg = load_config(None, SMALL)
    episodes = load_split(cfg.env.split, cfg.env)
    tasks = [EpisodeTask(0, cfg, agent_setup(cfg, "oracle"), i) for i in range(len(episodes))]
    fed = feed_order(tasks, cfg)
    assert sorted(t.index for t in fed) == list(range(len(episodes)))
    houses = [episodes[t.index].scene_id for t in fed]
    assert houses == sorted(houses, key=[episodes[i].scene_id for i in range(len(episodes))].index)   # contiguous
    for house in set(houses):
        lengths = [episodes[t.index].geodesic_distance for t in fed if episodes[t.index].scene_id == house]
        assert lengths == sorted(lengths, reverse=True)
