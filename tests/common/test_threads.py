"""common.threads: the thread budget a worker process gives every threading library."""
import os

import pytest

from calnav.common.threads import ENV, THREAD_VARS, pin_threads, thread_budget


@pytest.fixture
def restored_threads(monkeypatch):
    """pin_threads changes the environment and torch's threads: both put back afterwards."""
    import torch

    for var in (ENV, *THREAD_VARS):
        monkeypatch.delenv(var, raising=False)
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


def test_budget_defaults_to_all_cores_and_follows_pin(monkeypatch, restored_threads):
    import torch

    assert thread_budget() == (os.cpu_count() or 1)
    pin_threads(3)
    assert thread_budget() == 3 and all(os.environ[v] == "3" for v in THREAD_VARS)
    assert torch.get_num_threads() == 3   # torch, already loaded here, is told too
    monkeypatch.setenv(ENV, "zero")   # not a positive count: all cores
    assert thread_budget() == (os.cpu_count() or 1)
    with pytest.raises(ValueError, match=">= 1"):
        pin_threads(0)


def test_the_renderer_uses_the_budget(monkeypatch):
    from calnav.envs.render import Camera, Renderer
    from calnav.envs.scenes import load_scene, procedural_scene_id

    monkeypatch.setenv(ENV, "1")
    r = Renderer(load_scene(procedural_scene_id("val", 0)), Camera(width=32, height=24, hfov_deg=79.0))
    assert r.nthreads == 1 and len(r._bands) == 1
