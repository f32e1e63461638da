"""`calnav reproduce`: rerunning a directory's episodes with its own config matches its records;
a changed record is found and printed (exit 1); inputs that changed since, a missing episode
and a result-changing override are refused before anything runs (exit 2)."""
import json
from pathlib import Path

import pytest

from calnav.eval.cli import main
from calnav.eval.objectnav.reproduce import differences

REPO = Path(__file__).resolve().parents[3]
SMALL = ["env.resolution=32x24", "env.dataset.val_scenes=2", "env.dataset.episodes_per_scene=3", "run.workers=1"]


@pytest.mark.e2e
def test_a_crash_is_a_record_like_any_other(tmp_path, monkeypatch, capsys):
    """Every rerun crashing is a difference (exit 1), not a failed command; a crash record names
    its commit like any other record."""
    from calnav.common.provenance import running_commit
    from calnav.eval.objectnav import run as run_module

    run = tmp_path / "run"
    assert main(["objectnav", "--agent", "oracle", "--episodes", "0:2", "--output", str(run), *SMALL]) == 0

    def crash(*args, **kwargs):
        raise RuntimeError("boom")

    monkeypatch.setattr(run_module, "run_one_episode", crash)   # run.workers=1: episodes run in this process
    capsys.readouterr()
    assert main(["reproduce", str(run), "--episodes", "0:2", "--output", str(tmp_path / "crashed"),
                 "run.workers=1"]) == 1
    out = capsys.readouterr().out
    assert "status: 'ok' -> 'error'" in out and "2 of them differ" in out
    crashed = [json.loads(line) for line in (tmp_path / "crashed" / "episodes.jsonl").read_text().splitlines()]
    assert {r["status"] for r in crashed} == {"error"} and {r["commit"] for r in crashed} == {running_commit()}


def test_differences_by_hand():
    rec = {"index": 3, "success": 1.0, "spl": 0.5, "steps": 40, "stop_reason": "stop", "wall_time_s": 2.0,
           "commit": "a" * 40}
    same = {**rec, "spl": 0.5 + 1e-12, "wall_time_s": 9.0, "commit": "b" * 40, "ray_node": "n1"}
    assert differences(rec, same, tol=1e-9) == {}                    # float noise, where / when / which code aside
    assert differences(rec, {**rec, "spl": 0.6}, tol=1e-9) == {"spl": (0.5, 0.6)}
    assert differences(rec, {**rec, "spl": 0.6}, tol=0.2) == {}
    assert differences(rec, {**rec, "steps": 41, "stop_reason": "max_steps"}, tol=0.0) == \
        {"steps": (40, 41), "stop_reason": ("stop", "max_steps")}
    assert differences(rec, {**rec, "steps": 40.0}, tol=0.0) == {}   # 40 and 40.0 are the same number
    assert differences(rec, {**rec, "steps": True}, tol=0.0) == {"steps": (40, True)}
    assert differences(rec, {**rec, "steps": 40.0001}, tol=1e-3) == {}   # an int and a float within tol
    extra = {**rec, "status": "ok"}
    assert differences(rec, extra, tol=0.0) == {"status": (None, "ok")}   # a field one side lacks


@pytest.mark.e2e
def test_reproduce_matches_finds_a_change_and_refuses_bad_input(tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["objectnav", "--agent", "oracle", "--episodes", "0:2", "--output", str(run), *SMALL]) == 0
    capsys.readouterr()
    assert main(["reproduce", str(run), "--episodes", "0:2", "--output", str(tmp_path / "a"), "run.workers=1"]) == 0
    assert "2 episode(s) of" in capsys.readouterr().out and (tmp_path / "a" / "episodes.jsonl").is_file()

    # a record that says something else than the code does: found, named, exit 1
    lines = [json.loads(line) for line in (run / "episodes.jsonl").read_text().splitlines()]
    changed = next(r for r in lines if r["index"] == 1)
    steps = changed["steps"]
    changed["steps"] += 1
    (run / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines))
    assert main(["reproduce", str(run), "--episodes", "0:2", "--output", str(tmp_path / "b"), "run.workers=1"]) == 1
    out = capsys.readouterr().out
    assert f"episode 1 ({changed['episode_id']}): steps: {steps + 1} -> {steps}" in out and "1 of them differ" in out

    # records of other episodes under the same indices (scans made on another kind of machine):
    # refused, the code is not compared on them
    changed["steps"], geodesic = steps, changed["geodesic_distance"]
    changed["geodesic_distance"] += 0.5
    (run / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines))
    assert main(["reproduce", str(run), "--episodes", "0:2", "--output", str(tmp_path / "e"), "run.workers=1"]) == 2
    err = capsys.readouterr().err
    assert f"cannot reproduce: {run}'s records name other episodes: 1 of its 2 recorded episodes up to 2" in err
    assert not (tmp_path / "e").exists()
    changed["geodesic_distance"] = geodesic
    (run / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines))

    # refused before running: an episode without a record, an override that changes results,
    # a file the config reads that changed since the directory ran, --tol NaN, no directory
    assert main(["reproduce", str(run), "--episodes", "0:3", "--output", str(tmp_path / "c")]) == 2
    assert "holds no record of episode(s) 2" in capsys.readouterr().err
    assert main(["reproduce", str(run), "--episodes", "0:1", "agent.goal_threshold=0.3"]) == 2
    assert "agent.goal_threshold: a reproduction runs the directory's own config" in capsys.readouterr().err
    assert main(["reproduce", str(run), "--episodes", "0:1", "--output", str(run)]) == 2   # DIR itself
    assert "is DIR itself" in capsys.readouterr().err
    assert main(["reproduce", str(run), "--episodes", "0:1", "--output", str(tmp_path / "a")]) == 2
    assert "already holds records" in capsys.readouterr().err   # a resumed rerun would compare nothing rerun
    assert main(["reproduce", str(run), "--episodes", "0:1", "--tol", "nan"]) == 2
    assert "--tol must be in [0, 1000000000], got nan" in capsys.readouterr().err
    assert main(["reproduce", str(tmp_path / "nope"), "--episodes", "0:1"]) == 2
    assert "nope is not a directory" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["reproduce", str(tmp_path / "empty"), "--episodes", "0:1"]) == 2
    assert "empty/config.yaml is not a file" in capsys.readouterr().err
    assert not (tmp_path / "c").exists()   # nothing ran

    # the GLFS parameters a peanut run read, changed since: a rerun would test other parameters
    params = tmp_path / "glfs.json"
    params.write_text((REPO / "agent" / "weights" / "glfs_learned_rgb.json").read_text())
    glfs = tmp_path / "glfs_run"
    assert main(["objectnav", "--episodes", "0:1", "--output", str(glfs), *SMALL, "agent.segmenter=gt",
                 "mapping.fusion=glfs", f"mapping.glfs_params={params}", "env.max_episode_steps=10"]) == 0
    capsys.readouterr()
    params.write_text(params.read_text() + "\n")
    assert main(["reproduce", str(glfs), "--episodes", "0:1", "--output", str(tmp_path / "d")]) == 2
    err = capsys.readouterr().err
    assert "cannot reproduce" in err and "other input files: mapping.glfs_params" in err
    assert not (tmp_path / "d").exists()
