"""Rerun recordings, read back with Rerun's own chunk reader: an ObjectNav episode
(`--rerun N`), a recorded sequence's map (`calnav map --rerun`), `calnav view`, and the
one-line error without the [viz] extra."""
from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest

from calnav.eval.cli import main
from calnav.eval.config import agent_setup

# a mark, not a module-level importorskip: a run that deselects these tests (make test's habitat
# stage) does not report them as skipped
pytestmark = pytest.mark.skipif(importlib.util.find_spec("rerun") is None,
                                reason="the viz extra is installed by `make test`")

SMALL = ["env.resolution=64x48", "agent.map_resolution=64x48", "env.dataset.val_scenes=1",
         "env.dataset.episodes_per_scene=2", "agent.segmenter=gt", "agent.map_type=fused", "env.max_episode_steps=40"]


def _rows(table, column: str) -> list:
    return table.column(column).to_pylist()


def test_an_episode_recording_holds_the_agents_camera_frames_and_map(tmp_path):
    import gymnasium as gym

    import calnav.envs  # noqa: F401  (registers the env)
    from calnav.agent.policy import PeanutAgent
    from calnav.common.rerun_io import read_columns
    from calnav.eval.config import load_config
    from calnav.eval.objectnav.run import run_one_episode

    cfg = load_config(None, SMALL)
    env = gym.make("calnav/ObjectNav-v0", split="val", config=cfg.env)
    agent = PeanutAgent(agent_setup(cfg))
    plain = run_one_episode(env, agent, 0)
    rec = run_one_episode(env, agent, 0, rerun_dir=tmp_path)
    path = tmp_path / f"{rec['episode_id'].replace(':', '_')}.rrd"
    assert rec["rerun"] == str(path)
    assert {k: v for k, v in rec.items() if k not in ("rerun", "wall_time_s")} == \
        {k: v for k, v in plain.items() if k != "wall_time_s"}          # recording does not change the episode
    cols = read_columns(path)
    for entity in ("/world/camera", "/world/camera/rgb", "/world/camera/depth", "/world/camera/segmentation",
                   "/world/trajectory", "/world/map/class", "/world/map/confidence", "/map2d/topdown",
                   "/map2d/obstacles", "/map2d/explored", "/map2d/frontiers", "/map2d/detection",
                   "/map2d/goal_confidence", "/map2d/goals", "/metrics/action", "/metrics/distance_to_goal",
                   "/metrics/success"):
        assert entity in cols, entity
    steps = rec["steps"]
    camera = cols["/world/camera"]
    timed = [t for t in _rows(camera, "step") if t is not None]
    assert timed == list(range(1, steps + 1))   # one time point per step (and the static pinhole)
    assert sum(p is not None for p in _rows(camera, "Pinhole:image_from_camera")) == 1
    snapshots = _rows(cols["/world/map/class"], "step")
    assert snapshots == sorted(set(list(range(50, steps + 1, 50)) + [steps]))
    # the last snapshot is the agent's final map: same voxel centres, same confidences
    coords, probs = agent.state.voxels.observed_voxels()
    logged = np.asarray(_rows(cols["/world/map/confidence"], "Points3D:positions")[-1], np.float32)
    conf = np.asarray(_rows(cols["/world/map/confidence"], "confidence")[-1], np.float32)
    order_a, order_b = np.lexsort(coords.T), np.lexsort(logged.T)
    np.testing.assert_array_equal(logged[order_b], coords[order_a].astype(np.float32))
    np.testing.assert_array_equal(conf[order_b], probs.max(axis=1)[order_a].astype(np.float32))
    classes = np.asarray(_rows(cols["/world/map/class"], "Points3D:class_ids")[-1])
    np.testing.assert_array_equal(classes[np.lexsort(np.asarray(
        _rows(cols["/world/map/class"], "Points3D:positions")[-1], np.float32).T)], probs.argmax(axis=1)[order_a])
    dtg = _rows(cols["/metrics/distance_to_goal"], "Scalars:scalars")[-1]
    assert dtg[0] == pytest.approx(rec["distance_to_goal"])


def test_objectnav_rerun_option_writes_the_first_n_episodes(tmp_path):
    out = tmp_path / "run"
    assert main(["objectnav", "--episodes", "0:2", "--rerun", "1", "--output", str(out), "run.workers=1", *SMALL]) == 0
    recs = [json.loads(x) for x in (out / "episodes.jsonl").read_text().splitlines()]
    assert [bool(r.get("rerun")) for r in sorted(recs, key=lambda r: r["index"])] == [True, False]
    assert len(list((out / "rerun").glob("*.rrd"))) == 1


def test_map_rerun_holds_frames_the_map_and_correct_vs_wrong(tmp_path):
    from calnav.common.npz import load_versioned_npz
    from calnav.common.rerun_io import read_columns
    from calnav.eval.sequence.map_cmd import MAP_FORMAT_VERSION

    seq, out = tmp_path / "seq", tmp_path / "map"
    assert main(["export-sequence", "--frames", "8", "--resolution", "64x48", "--max-edge", "0.1",
                 "--output", str(seq)]) == 0
    assert main(["map", str(seq), "--layout", "scannet", "--segmenter", "noisy", "--output", str(out), "--rerun"]) == 0
    cols = read_columns(out / "map.rrd")
    assert _rows(cols["/world/camera"], "frame") == list(range(8))
    arrays, _ = load_versioned_npz(out / "map.npz", MAP_FORMAT_VERSION)
    logged = np.asarray(_rows(cols["/world/map/confidence"], "Points3D:positions")[0], np.float32)
    np.testing.assert_array_equal(logged, arrays["centres"])
    np.testing.assert_array_equal(np.asarray(_rows(cols["/world/map/confidence"], "confidence")[0], np.float32),
                                  arrays["probs"].max(axis=1))
    results = json.loads((out / "results.json").read_text())
    n_correct = len(_rows(cols["/world/map/correct"], "Points3D:positions")[0])
    n_wrong = len(_rows(cols["/world/map/wrong"], "Points3D:positions")[0])
    assert n_correct + n_wrong == results["labelled_voxels"] and n_wrong > 0
    assert "/world/mesh" in cols


def test_view_prints_the_command_without_a_display(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    out = tmp_path / "run"
    assert main(["objectnav", "--episodes", "0:1", "--rerun", "1", "--output", str(out), "run.workers=1", *SMALL]) == 0
    capsys.readouterr()
    assert main(["view", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "rerun --web-viewer" in printed and ".rrd" in printed
    assert main(["view", str(tmp_path / "missing")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_without_rerun_the_option_is_a_one_line_error_before_anything_runs(tmp_path, capsys, monkeypatch):
    import calnav.common.rerun_io as rio

    real = rio.importlib.import_module

    def no_rerun(name, *a, **k):
        if name == "rerun":
            raise ImportError("No module named 'rerun'")
        return real(name, *a, **k)

    monkeypatch.setattr(rio.importlib, "import_module", no_rerun)
    out = tmp_path / "run"
    assert main(["objectnav", "--episodes", "0:1", "--rerun", "1", "--output", str(out), *SMALL]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'pip install -e ".[viz]"' in err[0]
    assert not out.exists()   # nothing written
    seq = tmp_path / "seq"
    seq.mkdir()
    assert main(["map", str(seq), "--layout", "scannet", "--segmenter", "gt", "--output", str(out), "--rerun"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'pip install -e ".[viz]"' in err[0] and not out.exists()
    assert main(["view", str(tmp_path)]) == 2
    assert "calnav view needs Rerun" in capsys.readouterr().err


def test_view_refuses_files_that_are_not_recordings_or_maps(tmp_path, capsys, monkeypatch):
    from calnav.common import rerun_io

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    good = tmp_path / "good.rrd"
    palette = np.array([[0, 0, 0], [255, 255, 255]], np.uint8)
    rec = rerun_io.new_recording("test", good, ["a", "b"], palette)
    rerun_io.log_voxels(rec, "world/map", np.zeros((2, 3), np.float32), np.full((2, 2), 0.5, np.float32), 0.05,
                        palette, static=True)
    rec.flush()
    rec.disconnect()
    cut = tmp_path / "cut.rrd"   # a recording whose writer was killed: what it holds is viewable
    cut.write_bytes(good.read_bytes()[:100])
    for path in (good, cut):
        assert main(["view", str(path)]) == 0, capsys.readouterr().err
    capsys.readouterr()

    (tmp_path / "empty.rrd").write_bytes(b"")
    (tmp_path / "text.rrd").write_text("not a recording\n")
    (tmp_path / "header.rrd").write_bytes(b"RRF2" + bytes(range(1, 40)))   # the magic, then garbage
    (tmp_path / "map.npz").write_text("not a zip archive\n")
    run = tmp_path / "run"
    (run / "rerun").mkdir(parents=True)
    (run / "rerun" / "0.rrd").write_text("garbage")
    cases = {"empty.rrd": "is empty (0 bytes), not a Rerun recording",
             "text.rrd": "is not a Rerun recording: an .rrd file starts with 'RRF'",
             "header.rrd": "is not a readable Rerun recording",
             "map.npz": "is not a calnav map: not an .npz (zip) archive",
             "run": "0.rrd is not a Rerun recording"}
    for name, message in cases.items():
        assert main(["view", str(tmp_path / name)]) == 2, name
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0] and "allow_pickle" not in err[0], (name, err)
