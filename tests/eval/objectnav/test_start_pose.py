"""The agent is equally good whatever its start pose: the 2D map cannot alias the fused voxel
lattice, the maps are the same (up to rasterisation) in any frame, and the study's rotated
houses are the same houses (eval/objectnav/start_pose.py)."""
import math

import numpy as np
import pytest

from calnav.agent import projection as pj
from calnav.eval.config import load_config
from calnav.eval.objectnav.start_pose import VARIANTS, PoseVariant, reexpress_obs, lockstep_map_stats, parse_variants, rotated_setup

VOXEL_M = 0.05


def test_lattice_aligned_origin_hand_computed_and_no_aliasing():
    origin = pj.lattice_aligned_origin(np.zeros(2), 40.0, VOXEL_M)
    np.testing.assert_allclose(origin, [-19.975, -19.975])       # floor(-400) + 0.5 voxels
    np.testing.assert_allclose(pj.lattice_aligned_origin(np.array([0.31, -0.07]), 40.0, None), [-19.69, -20.07])
    steps = np.arange(-300, 300)[:, None] * np.ones((1, 2))
    for start in (np.zeros(2), np.array([0.013, 0.027]), np.array([100.0, -100.0])):
        centres = (np.rint(start / VOXEL_M) + steps) * VOXEL_M     # voxel centres along a diagonal through the start
        cells, inside = pj.cell_of(centres, pj.lattice_aligned_origin(start, 40.0, VOXEL_M), VOXEL_M, 800)
        assert inside.all() and (np.diff(cells) == 801).all()     # one voxel column per cell, none skipped
    cells, _ = pj.cell_of(steps * VOXEL_M, np.zeros(2) - 20.0, VOXEL_M, 800)  # the old corner, on the lattice
    assert (np.diff(cells) != 801).any()                          # what went wrong: columns skip cells


def test_frame_obs_round_trips_to_the_world_pose():
    obs = {"gps": np.array([1.0, -2.0], np.float32), "compass": np.array([0.3], np.float32)}
    w = reexpress_obs(obs, VARIANTS["world"], np.array([5.0, 7.0]), math.pi / 2)
    # start facing +y: forward 1 -> +y, right -2 (= left 2) -> -x
    np.testing.assert_allclose(w["gps"], [3.0, -8.0], atol=1e-5)            # world (3, 8) as (x, -y)
    assert w["compass"][0] == pytest.approx(0.3 + math.pi / 2, abs=1e-6)
    shifted = reexpress_obs(obs, PoseVariant("s", offset_m=(0.5, 0.25), yaw_deg=90.0), (0, 0), 0.0)
    np.testing.assert_allclose(shifted["gps"], [0.5 - 2.0, -(0.25 + 1.0)], atol=1e-5)
    with pytest.raises(ValueError, match="valid: world, start"):
        parse_variants("start,nope")


@pytest.fixture(scope="module")
def small_cfg():
    return load_config(None, ["env.resolution=160x120", "env.dataset.val_scenes=1", "env.dataset.episodes_per_scene=4",
                              "agent.map_size_m=24", "mapping.initial_alloc_mb=32", "agent.map_resolution=80x60"])


def test_maps_agree_across_frames(small_cfg):
    """After the initial spin, the maps in the world frame, the start frame and a rotated,
    shifted frame hold the same numbers of semantic / goal / explored cells (up to the
    rasterisation of rotated walls). Before the lattice alignment the start frame lost a third
    of its semantic cells."""
    variants = [VARIANTS["world"], VARIANTS["start"], VARIANTS["start_rotated"]]
    rows = lockstep_map_stats(small_cfg, 0, variants, steps=12)
    last = {r["variant"]: r for r in rows if r["step"] == 11}
    ref = last["world"]
    assert ref["semantic_cells"] > 200
    for name in ("start", "start_rotated"):
        for key in ("semantic_cells", "explored_cells", "goal_cells"):
            assert abs(last[name][key] - ref[key]) <= 0.08 * ref[key] + 2, (name, key, last[name][key], ref[key])


def test_rotated_house_is_the_same_house(small_cfg, tmp_path):
    import gymnasium as gym

    from calnav import envs
    from calnav.envs.episodes import load_split

    env_cfg = small_cfg.env
    episodes = load_split("val", env_cfg, progress=False)[:1]
    rot_cfg, rot_eps = rotated_setup(env_cfg, episodes, 37.0, tmp_path / "houses")
    a = gym.make(envs.ENV_ID, split="val", config=env_cfg, episodes=episodes)
    b = gym.make(envs.ENV_ID, split="val", config=rot_cfg, episodes=rot_eps)
    oa, ia = a.reset(options={"episode_index": 0})
    ob, ib = b.reset(options={"episode_index": 0})
    # both at their start: gps is 0 up to habitat-lab's float32 rounding of the start position
    np.testing.assert_allclose(ob["gps"], oa["gps"], atol=1e-6)
    np.testing.assert_allclose(ob["compass"], oa["compass"], atol=1e-6)
    assert np.mean(np.abs(ob["depth"] - oa["depth"]) < 0.01) > 0.98       # the same view
    assert np.mean(ob["semantic"] == oa["semantic"]) > 0.98
    assert ib["distance_to_goal"] == pytest.approx(ia["distance_to_goal"], abs=0.25)   # grid rasterised anew


def test_start_pose_cli_writes_its_results_directory_and_refuses_another_config(tmp_path, capsys):
    """`calnav start-pose` runs on the shared backend and its output is a results directory
    (config check, --force, atomic summaries), like every other command's."""
    import json

    from calnav.eval.cli import main

    out = tmp_path / "sp"
    tiny = ["env.resolution=64x48", "agent.map_resolution=64x48", "agent.segmenter=gt", "env.max_episode_steps=30",
            "env.dataset.val_scenes=1", "env.dataset.episodes_per_scene=2"]
    args = ["start-pose", "--episodes", "1", "--variants", "world,start", "--workers", "1", "--output", str(out)]
    assert main([*args, *tiny]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary) == {"world", "start"} and all(s["n"] == 1 for s in summary.values())
    assert (out / "summary.csv").read_text().startswith("variant,successes,n,success,spl")
    for v in ("world", "start"):   # each variant is a results directory of the shared episode runner
        assert len((out / v / "episodes.jsonl").read_text().splitlines()) == 1
        assert json.loads((out / v / "summary.json").read_text())["count"] == 1
    assert main([*args, *tiny, "env.max_episode_steps=20"]) == 2
    assert "different config" in capsys.readouterr().err
    assert main([*args, "--force", *tiny, "env.max_episode_steps=20"]) == 0


def test_start_pose_crash_is_a_record_and_a_rerun_resumes(tmp_path, monkeypatch):
    """The frame study runs through the episode runner every ObjectNav command uses: a crashing
    episode is an error record (it used to kill the whole study), counted as a failure in the
    shared summary, retried by the rerun; finished episodes are not run again (the study used
    to truncate its episodes.jsonl on every run)."""
    import json

    import calnav.eval.objectnav.run as run
    from calnav.eval.cli import main

    out = tmp_path / "sp"
    tiny = ["env.resolution=64x48", "agent.map_resolution=64x48", "agent.segmenter=gt", "env.max_episode_steps=20",
            "env.dataset.val_scenes=1", "env.dataset.episodes_per_scene=2"]
    args = ["start-pose", "--episodes", "2", "--variants", "start", "--workers", "1", "--output", str(out), *tiny]
    real, calls = run.run_one_episode, []

    def crash_on_1(env, agent, index, video_dir=None, rerun_dir=None):
        calls.append(index)
        if index == 1 and len(calls) <= 2:
            raise RuntimeError("boom")
        return real(env, agent, index, video_dir, rerun_dir)

    monkeypatch.setattr(run, "run_one_episode", crash_on_1)
    assert main(args) == 0
    recs = [json.loads(x) for x in (out / "start" / "episodes.jsonl").read_text().splitlines()]
    assert sorted(r["status"] for r in recs) == ["error", "ok"]
    assert "boom" in next(r for r in recs if r["status"] == "error")["error"]   # (in any completion order)
    summary = json.loads((out / "summary.json").read_text())["start"]
    assert summary["n"] == 2 and summary["failed"] == 1 and summary["successes"] <= 1
    assert main(args) == 0 and sorted(calls[:2]) == [0, 1] and calls[2:] == [1]   # only the crashed one reruns
    recs = [json.loads(x) for x in (out / "start" / "episodes.jsonl").read_text().splitlines()]
    assert sorted(r["index"] for r in recs) == [0, 1] and all(r["status"] == "ok" for r in recs)
    assert json.loads((out / "summary.json").read_text())["start"]["failed"] == 0


def test_a_changed_variant_definition_is_not_resumed(tmp_path, capsys, monkeypatch):
    """A variant's directory records its definition (variant.json): if VARIANTS is edited, the
    old episodes are not reused under the new definition (refused; --force discards them)."""
    import json

    import calnav.eval.objectnav.start_pose as sp
    from calnav.eval.cli import main

    out = tmp_path / "sp"
    tiny = ["env.resolution=64x48", "agent.map_resolution=64x48", "agent.segmenter=gt", "env.max_episode_steps=10",
            "env.dataset.val_scenes=1", "env.dataset.episodes_per_scene=2"]
    args = ["start-pose", "--episodes", "1", "--variants", "start_offset", "--workers", "1", "--output", str(out), *tiny]
    assert main(args) == 0
    assert json.loads((out / "start_offset" / "variant.json").read_text())["offset_m"] == [0.013, 0.027]
    monkeypatch.setitem(sp.VARIANTS, "start_offset", sp.PoseVariant("start_offset", offset_m=(0.5, 0.5)))
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "another definition of variant 'start_offset'" in err and "--force" in err
    assert main([*args, "--force"]) == 0
    assert json.loads((out / "start_offset" / "variant.json").read_text())["offset_m"] == [0.5, 0.5]
    assert len((out / "start_offset" / "episodes.jsonl").read_text().splitlines()) == 1
