"""A plugin that calls ``sys.exit()`` or raises ``KeyboardInterrupt`` itself fails its own task,
not calnav: in its factory, a one-line error before anything is written; on a frame, an error
record for that episode while the others are kept (in-process and in a pool of 2 workers)."""
from __future__ import annotations

import pytest

from calnav.eval.cli import main
from tests.conftest import read_records

PLUGINS = "tests.agent.segmenter_plugins"
SMALL = ["env.resolution=64x48", "env.dataset.val_scenes=1", "env.dataset.episodes_per_scene=2",
         "env.max_episode_steps=30"]
EXITED = (f"segmenter {PLUGINS}:exits_on_call called sys.exit(); a plugin reports a failure by raising an "
          "exception, calnav does not exit for it")


def _objectnav(out, segmenter: str, workers: int) -> int:
    return main(["objectnav", "--episodes", "0:2", "--output", str(out), *SMALL, f"run.workers={workers}",
                 f"agent.segmenter={PLUGINS}:{segmenter}"])


@pytest.mark.parametrize("workers", [1, 2])
@pytest.mark.parametrize("factory,message", [
    ("exits_in_factory", "its factory called sys.exit(); a plugin reports a failure by raising an exception, "
                         "calnav does not exit for it"),
    ("interrupts_in_factory", "its factory raised KeyboardInterrupt itself (no Ctrl-C was pressed)"),
])
def test_a_factory_that_exits_is_a_one_line_error(tmp_path, capsys, workers, factory, message):
    out = tmp_path / "run"
    assert _objectnav(out, factory, workers) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"calnav objectnav: error: segmenter plugin '{PLUGINS}:{factory}': {message}"
    assert not out.exists()


@pytest.mark.parametrize("segmenter,error,workers", [
    ("exits_on_call", f"UserCodeExit: {EXITED}", 1),
    ("exits_on_call", f"UserCodeExit: {EXITED}", 2),
    ("interrupts_on_call", f"UserCodeExit: segmenter {PLUGINS}:interrupts_on_call raised KeyboardInterrupt itself "
                           "(no Ctrl-C was pressed)", 1),
])
def test_a_plugin_that_exits_on_a_frame_fails_that_episode(tmp_path, capsys, segmenter, error, workers):
    """The plugin stops on its EXIT_CALL-th frame: the episode of that frame gets an error
    record, the episodes before and after it run (in-process: one instance segments both
    episodes; with 2 workers each worker's instance stops in its first episode)."""
    out = tmp_path / "run"
    rc = _objectnav(out, segmenter, workers)
    records = read_records(out)
    assert sorted(records) == [0, 1]
    failed = [r for r in records.values() if r["status"] == "error"]
    assert failed and all(r["error"] == error for r in failed)
    assert len(failed) == (1 if workers == 1 else 2)
    # a run whose every episode failed says so (exit 2); otherwise its table is printed
    assert rc == (2 if len(failed) == len(records) else 0)
    assert "Traceback" not in capsys.readouterr().err
