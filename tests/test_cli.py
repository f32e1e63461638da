"""End-to-end `calnav` commands in a small form: objectnav (resume, config refusal, crash
records), view-episode, bench."""
import json

import pytest

from eval.cli import main
from eval.objectnav import load_records
from eval.stats import format_metrics_table, mean_sem, summarize

SMALL = ["env.resolution=32x24", "env.dataset.val_scenes=2", "env.dataset.episodes_per_scene=3"]

pytestmark = pytest.mark.e2e


def test_mean_sem_known_numbers():
    m, s = mean_sem([1.0, 0.0, 1.0, 1.0])
    assert m == pytest.approx(0.75)
    assert s == pytest.approx(0.5 / 2)  # sample std 0.5, n = 4
    assert mean_sem([0.3]) == (0.3, 0.0)
    summary = summarize([
        {"category": "bed", "success": 1.0, "spl": 0.5, "softspl": 0.5, "distance_to_goal": 0.0, "status": "ok"},
        {"category": "bed", "success": 0.0, "spl": 0.0, "softspl": 0.2, "distance_to_goal": 2.0, "status": "ok"},
        {"index": 3, "status": "error", "error": "boom"},
    ])
    assert summary["count"] == 3 and summary["failed"] == 1
    assert summary["success"] == pytest.approx(1 / 3)  # a crashed episode is a failure
    assert summary["per_category"]["bed"]["spl"] == pytest.approx(0.25)
    assert "| oracle | 0.333 (0.333)" in format_metrics_table([("oracle", summary)])


def test_objectnav_oracle_run_resume_and_refusal(tmp_path, capsys):
    out = tmp_path / "run"
    args = ["objectnav", "--agent", "oracle", "--episodes", "0:4", "--output", str(out), "run.workers=1", *SMALL]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "| oracle | 1.000 (0.000)" in printed
    summary = json.loads((out / "summary.json").read_text())
    assert summary["count"] == 4 and summary["success"] == 1.0 and summary["spl"] >= 0.9
    records = load_records(out / "episodes.jsonl")
    assert sorted(r["index"] for r in records) == [0, 1, 2, 3]
    assert {"episode_id", "category", "scene", "success", "spl", "softspl", "distance_to_goal", "steps",
            "path_length", "wall_time_s", "stop_reason"} <= set(records[0])

    # simulate an interrupted run: drop two finished episodes and tear the last line
    lines = (out / "episodes.jsonl").read_text().splitlines()
    (out / "episodes.jsonl").write_text("\n".join(lines[:2]) + "\n" + lines[2][: len(lines[2]) // 2])
    assert main(args[:4] + ["0:6"] + args[5:]) == 0
    records = load_records(out / "episodes.jsonl")
    assert sorted(r["index"] for r in records) == [0, 1, 2, 3, 4, 5]  # none missing, none twice

    # a different config in the same directory is refused, --force discards
    other = args + ["env.max_episode_steps=100"]
    assert main(other) == 2
    assert "holds results of a different config" in capsys.readouterr().err
    assert main(other + ["--force"]) == 0
    assert len(load_records(out / "episodes.jsonl")) == 4


def test_objectnav_bad_input(tmp_path, capsys):
    base = ["objectnav", "--output", str(tmp_path / "r"), *SMALL]
    assert main(base + ["--episodes", "0:999"]) == 2
    assert "outside the split" in capsys.readouterr().err
    assert main(base + ["--agent", "nope"]) == 2
    assert "valid agents: oracle" in capsys.readouterr().err
    assert main(base + ["mapping.fusion=bayes"]) == 2
    assert "mapping.fusion" in capsys.readouterr().err


def test_view_episode_writes_pngs(tmp_path):
    out = tmp_path / "view"
    assert main(["view-episode", "--episode", "1", "--output", str(out), *SMALL]) == 0
    for name in ("topdown.png", "frames.png"):
        assert (out / name).stat().st_size > 10_000


def test_bench_quick_has_required_figures(tmp_path):
    path = tmp_path / "bench.json"
    assert main(["bench", "--quick", "--only", "env", "--output", str(path)]) == 0
    figures = json.loads(path.read_text())
    for key in ("env.render_ms_640x480", "env.raycast_ms_640x480", "env.render_ratio_640x480",
                "env.steps_per_s_640x480", "env.steps_per_s_160x120"):
        assert figures[key] > 0
