"""Shared test set-up: an isolated calnav cache per test session (scenes and episodes are
generated fresh, so generation itself is under test), and the small/full switch."""
import atexit
import os
import shutil
import signal
import tempfile

import pytest

# Set before any calnav module reads it (cache_dir() reads the variable at call time); removed
# when the test process exits (each run used to leave ~10 MB of scenes and episodes in /tmp).
os.environ["CALNAV_CACHE"] = _CACHE = tempfile.mkdtemp(prefix="calnav-test-cache-")
atexit.register(shutil.rmtree, _CACHE, ignore_errors=True)
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # as eval/cli.py: no spinning OpenMP workers

FULL = os.environ.get("CALNAV_FULL_TESTS") == "1"


def require_habitat() -> None:
    """Skip the calling test module when habitat-lab is absent (the main .venv), unless
    CALNAV_REQUIRE_HABITAT=1 (`make test`'s run in .venv-habitat), where that is an error."""
    import importlib.util

    if importlib.util.find_spec("habitat") is None:
        if os.environ.get("CALNAV_REQUIRE_HABITAT") == "1":
            raise RuntimeError("CALNAV_REQUIRE_HABITAT=1 but habitat-lab is not importable in this Python")
        pytest.skip("habitat-lab is not installed here (make test runs these in .venv-habitat)",
                    allow_module_level=True)


def pytest_configure(config):
    """A suite started in the background of a non-interactive shell (`make test &`, nohup)
    inherits SIGINT ignored, and so would every process it starts; the Ctrl-C tests send real
    SIGINTs, so Python's own handler is restored (a child process then starts with it too)."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def read_records(run_dir) -> dict[int, dict]:
    """A results directory's episodes.jsonl as {episode index: record}."""
    import json
    from pathlib import Path

    return {r["index"]: r for r in map(json.loads, (Path(run_dir) / "episodes.jsonl").read_text().splitlines())}


def assert_same_records(a: dict[int, dict], b: dict[int, dict], tol: float) -> None:
    """Two runs' records agree episode by episode: the same fields, floats within ``tol``, the
    rest (steps, collisions, stop reason: the same actions) equal; wall time aside."""
    for i in a:
        h, c = dict(a[i]), dict(b[i])
        h.pop("wall_time_s"), c.pop("wall_time_s")
        assert h.keys() == c.keys()
        for k in h:
            if isinstance(h[k], float):
                assert abs(h[k] - c[k]) < tol, (i, k, h[k], c[k])
            else:
                assert h[k] == c[k], (i, k, h[k], c[k])


def results_dir_like(path) -> str:
    """A results directory as `calnav objectnav` leaves it: the shipped config as its
    config.yaml and an empty records file (for commands that read one)."""
    import shutil
    from pathlib import Path

    from calnav.common.provenance import REPO_ROOT

    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    shutil.copy(REPO_ROOT / "configs" / "objectnav.yaml", path / "config.yaml")
    (path / "episodes.jsonl").write_text("")
    return str(path)


def small_or_full(small, full):
    """`make test` runs end-to-end checks in a small form; `make test-full` at full size."""
    return full if FULL else small


@pytest.fixture(scope="session")
def small_env_config():
    """An EnvConfig with a small val/test split and low resolution, for fast env tests."""
    from calnav.eval.config import load_config

    return load_config(None, [
        "env.resolution=64x48", "env.dataset.val_scenes=2", "env.dataset.test_scenes=2",
        "env.dataset.episodes_per_scene=4",
    ]).env


@pytest.fixture(scope="session")
def local_ray():
    """A small local Ray instance (2 CPUs) for the session's Ray tests (eval backends and the
    runner): started once, not once per module; its workers import this checkout and read the
    session's cache. Tests that need a Ray instance of their own (a killed driver, a two-node
    cluster) start it in a subprocess or by address."""
    ray = pytest.importorskip("ray", reason="the ray extra is installed by `make test`")
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    env = {k: os.environ[k] for k in ("CALNAV_CACHE", "OMP_WAIT_POLICY") if k in os.environ}
    env["PYTHONPATH"] = os.pathsep.join([str(repo), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, runtime_env={"env_vars": env})
    yield ray
    ray.shutdown()
