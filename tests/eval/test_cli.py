"""End-to-end `calnav` commands in a small form: objectnav (resume, config refusal, crash
records), view-episode, bench."""
import csv
import json

import pytest

from calnav.common.provenance import git_commit
from calnav.eval.cli import main
from calnav.eval.stats import format_metrics_table, mean_sem, summarize

SMALL = ["env.resolution=32x24", "env.dataset.val_scenes=2", "env.dataset.episodes_per_scene=3"]

pytestmark = pytest.mark.e2e


def load_records(path) -> list[dict]:
    """Every line of a records file as JSON (strict: a damaged or duplicate line shows)."""
    return [json.loads(line) for line in path.read_text().splitlines()]


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
            "path_length", "wall_time_s", "stop_reason", "commit"} <= set(records[0])
    assert {r["commit"] for r in records} == {git_commit()}      # which code ran each episode

    # simulate an interrupted run: drop two finished episodes and tear the last line
    lines = (out / "episodes.jsonl").read_text().splitlines()
    (out / "episodes.jsonl").write_text("\n".join(lines[:2]) + "\n" + lines[2][: len(lines[2]) // 2])
    assert main(args[:4] + ["0:6"] + args[5:]) == 0
    records = load_records(out / "episodes.jsonl")
    assert sorted(r["index"] for r in records) == [0, 1, 2, 3, 4, 5]  # none missing, none twice
    capsys.readouterr()
    assert main(args[:4] + ["0:6"] + args[5:]) == 0   # the same range again: said, not silently re-summed
    assert f"nothing to run: all 6 episodes are recorded in {out}" in capsys.readouterr().out
    assert len(load_records(out / "episodes.jsonl")) == 6

    # a different config in the same directory is refused, --force discards
    other = args + ["env.max_episode_steps=100"]
    assert main(other) == 2
    # the refusal names the key that differs, with both values
    assert "holds results of a different config" in (err := capsys.readouterr().err)
    assert "config.yaml: env.max_episode_steps: 500 there, 100 here); use another --output" in err
    # so is another agent: its episodes would silently mix with the oracle's
    peanut = [a if a != "oracle" else "peanut" for a in args]
    assert main(peanut) == 2
    assert "holds results of a different config" in capsys.readouterr().err
    assert main(other + ["--force"]) == 0
    assert len(load_records(out / "episodes.jsonl")) == 4


def test_range_past_the_splits_capacity_is_refused_before_any_scene_is_generated(tmp_path, monkeypatch, capsys):
    """2 val scenes x 3 episodes hold at most 6 episodes: 100000:100003 is refused at once, by
    that bound, with no scene generated and nothing written."""
    monkeypatch.setenv("CALNAV_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "r"
    assert main(["objectnav", "--output", str(out), *SMALL, "--episodes", "100000:100003"]) == 2
    err = capsys.readouterr().err
    assert "is outside the split, which has at most 6 episodes (2 val scenes x dataset.episodes_per_scene 3)" in err
    assert not list((tmp_path / "cache").rglob("*.npz")) and not list((tmp_path / "cache").rglob("*.json.gz"))
    assert not out.exists()


def test_objectnav_bad_input(tmp_path, capsys):
    base = ["objectnav", "--output", str(tmp_path / "r"), *SMALL]
    assert main(base + ["--episodes", "0:999"]) == 2
    assert "outside the split" in capsys.readouterr().err
    assert main(base + ["--agent", "nope"]) == 2
    assert "run: unknown agent 'nope' for run.agent; valid choices: peanut, oracle" in capsys.readouterr().err
    assert main(base + ["mapping.fusion=bayes"]) == 2
    assert "mapping.fusion" in capsys.readouterr().err


def test_view_episode_writes_pngs(tmp_path):
    out = tmp_path / "view"
    assert main(["view-episode", "--episode", "1", "--output", str(out), *SMALL]) == 0
    for name in ("topdown.png", "frames.png"):
        assert (out / name).stat().st_size > 10_000
    # past the split's most episodes (2 houses x 3): refused by that bound before any house is made
    assert main(["view-episode", "--episode", "100000", "--output", str(tmp_path / "v2"), *SMALL]) == 2
    assert not (tmp_path / "v2").exists()


def test_bench_quick_has_required_figures(tmp_path):
    path = tmp_path / "bench.json"
    assert main(["bench", "--quick", "--only", "env", "--output", str(path)]) == 0
    figures = json.loads(path.read_text())
    for key in ("env.render_ms_640x480", "env.raycast_ms_640x480", "env.render_ratio_640x480",
                "env.steps_per_s_640x480", "env.steps_per_s_160x120"):
        assert figures[key] > 0


def test_bench_quick_scan_figures(tmp_path):
    path = tmp_path / "bench.json"
    assert main(["bench", "--quick", "--only", "scan", "--output", str(path)]) == 0
    figures = json.loads(path.read_text())
    for key in ("scan.build_s", "scan.triangles", "scan.render_ms_160x120", "scan.render_ratio_160x120",
                "scan.agent_hz_160x120"):
        assert figures[key] > 0


def test_bench_quick_segmenter_figures(tmp_path):
    """The segmenter section times both learned networks, traced and eager, in one loop."""
    path = tmp_path / "bench.json"
    assert main(["bench", "--quick", "--only", "segmenter", "--output", str(path)]) == 0
    figures = json.loads(path.read_text())
    for model in ("learned_rgb", "learned_rgbd"):
        for key in ("ms_160x120", "eager_ms_160x120", "trace_speedup", "ms_640x480"):
            assert figures[f"segmenter.{model}.{key}"] > 0

def test_scan_houses_writes_the_quality_table(tmp_path, capsys):
    out = tmp_path / "q"
    fast = ["env.dataset.scanning.frames=40", "env.dataset.scanning.resolution=64x48",
            "env.dataset.scanning.voxel_m=0.06", "env.dataset.scanning.triangles_per_m2=0", "run.workers=1"]
    assert main(["scan-houses", "--splits", "val", "--houses", "1", "--output", str(out), *fast]) == 0
    rows = list(csv.DictReader((out / "quality.csv").open()))
    assert [r["scene_id"] for r in rows] == ["house_val_0000"]
    assert 0 <= float(rows[0]["floor_missing"]) <= 1 and float(rows[0]["triangles"]) > 0
    assert "real ScanNet apartment" in (out / "quality.md").read_text()
    assert main(["scan-houses", "--splits", "nope", "--output", str(tmp_path / "bad")]) == 2
    assert "valid splits" in capsys.readouterr().err and not (tmp_path / "bad").exists()


PEANUT_TINY = ["--agent", "peanut", "--episodes", "1", "run.workers=1", "env.resolution=64x48",
               "env.dataset.val_scenes=1", "env.dataset.episodes_per_scene=2", "env.max_episode_steps=25"]


@pytest.mark.parametrize("overrides, label", [
    (["agent.segmenter=learned_rgb", "mapping.fusion=glfs"], "peanut (learned_rgb + glfs)"),
    (["agent.map_type=ndf"], "peanut (gt + ndf)"),      # NDF fuses nothing: mapping.fusion is not its map
    (["run.agent=oracle"], "oracle"),                   # no semantic map at all
])
def test_run_label_names_what_the_agent_maps_from(overrides, label):
    from calnav.eval.config import load_config
    from calnav.eval.stats import run_label

    assert run_label(load_config(None, overrides)) == label


def test_objectnav_video_same_metrics_and_plots(tmp_path, capsys):
    import imageio.v2 as imageio

    assert main(["objectnav", "--output", str(tmp_path / "plain"), *PEANUT_TINY]) == 0
    # the table names what the agent mapped from: the default config's ground-truth segmenter
    assert "| peanut (gt + averaging) |" in capsys.readouterr().out
    assert main(["objectnav", "--output", str(tmp_path / "vid"), "--video", "1", *PEANUT_TINY]) == 0
    videos = list((tmp_path / "vid" / "videos").glob("*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 1000 and ":" not in videos[0].name
    assert not (tmp_path / "plain" / "videos").exists()
    plain, vid = (load_records(tmp_path / d / "episodes.jsonl")[0] for d in ("plain", "vid"))
    n_frames = sum(1 for _ in imageio.get_reader(videos[0]))
    assert n_frames == vid["steps"] > 0  # one panel per action
    for key in ("success", "spl", "softspl", "distance_to_goal", "steps", "path_length", "collisions"):
        assert vid[key] == plain[key], key
    for name in ("metrics.png", "per_category_success.png"):
        assert (tmp_path / "vid" / "plots" / name).stat().st_size > 1000


def test_objectnav_video_needs_a_map_agent(tmp_path, capsys):
    args = ["objectnav", "--agent", "oracle", "--episodes", "1", "--video", "1", "--output", str(tmp_path / "o"),
            *SMALL]
    assert main(args) == 2
    assert "agent 'oracle' has none" in capsys.readouterr().err


def test_objectnav_multirun_dirs_resume_and_comparison(tmp_path, capsys):
    out = tmp_path / "mr"
    args = ["objectnav", "-m", "--agent", "oracle", "--episodes", "0:2", "--output", str(out), "run.workers=1",
            *SMALL, "env.max_episode_steps=400,500", "env.success_distance_m=0.1,0.2"]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "| env.max_episode_steps | env.success_distance_m | SPL | Success | SoftSPL | DTG | N |" in printed
    subdirs = sorted(p.name for p in out.iterdir() if p.is_dir())
    assert subdirs == [f"env.max_episode_steps={s}__env.success_distance_m={d}"
                       for s in (400, 500) for d in (0.1, 0.2)]
    for sub in subdirs:
        assert len(load_records(out / sub / "episodes.jsonl")) == 2
        assert (out / sub / "summary.json").exists() and (out / sub / "plots" / "metrics.png").exists()
    md = (out / "comparison.md").read_text()
    assert md.count("| 1.000 (0.000) |") == 4 and "| 400 | 0.2 |" in md
    header = (out / "comparison.csv").read_text().splitlines()[0].split(",")
    assert header[:4] == ["env.max_episode_steps", "env.success_distance_m", "spl", "spl_sem"]
    assert (out / "comparison.png").stat().st_size > 1000
    # rerun: every combination resumes (nothing re-run, nothing appended)
    before = {s: (out / s / "episodes.jsonl").read_text() for s in subdirs}
    assert main(args) == 0
    assert before == {s: (out / s / "episodes.jsonl").read_text() for s in subdirs}


def test_overrides_on_both_sides_of_an_option_are_accepted():
    from calnav.eval.cli import parse_args

    args = parse_args(["objectnav", "a.b=1", "--episodes", "0:2", "c.d=2", "--force"])
    assert args.command == "objectnav" and args.overrides == ["a.b=1", "c.d=2"]
    assert args.episodes == "0:2" and args.force
    args = parse_args(["compare", "r1", "--output", "o", "r2"])
    assert args.runs == ["r1", "r2"] and args.output == "o"


def test_habitat_benchmark_names_the_install_when_habitat_lab_is_missing(tmp_path, capsys):
    import importlib.util

    if importlib.util.find_spec("habitat") is not None:
        pytest.skip("habitat-lab is installed here: tests/envs/test_habitat.py covers habitat-benchmark")
    assert main(["habitat-benchmark", "--output", str(tmp_path / "h"), "env.dataset.val_scenes=2"]) == 2
    err = capsys.readouterr().err
    assert "habitat-lab is not installed" in err and "make habitat-setup" in err and 'pip install -e ".[habitat]"' in err
    assert not (tmp_path / "h").exists()


@pytest.mark.parametrize("where", ["file", "under_file"])
def test_cache_that_is_a_file_is_one_line_before_writing(tmp_path, capsys, monkeypatch, where):
    """CALNAV_CACHE pointing at a file (or below one) is one line, not a traceback."""
    blocker = tmp_path / "cache"
    blocker.write_text("not a directory")
    monkeypatch.setenv("CALNAV_CACHE", str(blocker if where == "file" else blocker / "sub"))
    out = tmp_path / "run"
    assert main(["objectnav", "--agent", "oracle", "--episodes", "0:1", "--output", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "point CALNAV_CACHE at a writable directory" in err[0] and not out.exists()


def test_ctrl_c_is_one_line_that_says_how_to_resume(tmp_path, capsys, monkeypatch):
    import calnav.eval.objectnav.run as run

    def interrupted(args, configs):
        raise KeyboardInterrupt

    monkeypatch.setattr(run, "main_objectnav", interrupted)
    assert main(["objectnav", "--agent", "oracle", "--episodes", "0:1", "--output", str(tmp_path / "r")]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["calnav objectnav: interrupted; finished work is kept: rerun the same command to resume"]


@pytest.mark.parametrize("command", [
    ["fit-glfs", "--segmenter", "gt"],
    ["train-segmenter", "--segmenter", "learned_rgb"],
    ["eval-segmenter", "--segmenter", "gt", "--split", "test", "--frames", "1"],
])
def test_output_file_under_a_file_fails_before_any_work(tmp_path, capsys, command):
    """--output under a file, or a directory, fails before any work (not after training with "File exists")."""
    blocker = tmp_path / "blocker"
    blocker.write_text("x")
    assert main([*command, "--output", str(blocker / "out.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{blocker} is a file, not a directory" in err[0]
    assert main([*command, "--output", str(tmp_path)]) == 2
    assert "is a directory; give a file name" in capsys.readouterr().err


@pytest.mark.parametrize("command", [
    ["view-episode", "--episode", "0"],
    ["export-sequence", "--scene", "house_val_0000"],
])
def test_output_directory_that_is_a_file_is_one_line(tmp_path, capsys, command):
    """--output that is a file (or under one) is one line, not a NotADirectoryError / FileExistsError traceback."""
    blocker = tmp_path / "blocker"
    blocker.write_text("x")
    for out in (blocker, blocker / "sub"):
        rc = main([*command, "--output", str(out)])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and len(err) == 1 and "is a file, not a directory" in err[0], err


@pytest.mark.parametrize("argv", [
    ["objectnav", "--agent", "oracle", "run.agent=peanut"],
    ["habitat-benchmark", "--agent", "oracle", "run.agent=peanut"],
    ["start-pose", "--workers", "2", "run.workers=1"],
    ["calibrate-map", "--sequences", "list.txt", "sequences.list=other.txt"],
])
def test_a_shorthand_never_silently_overrides_the_same_key(tmp_path, capsys, argv):
    """``--agent`` / ``--workers`` / ``--sequences`` and the key they stand for, both given: one
    line naming both, nothing written (the shorthand never wins silently)."""
    out = tmp_path / "out"
    assert main([*argv, "--output", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "both set" in err[0] and "give one of them" in err[0], err
    assert not out.exists()


def test_bench_quick_study_speed_figures(tmp_path, monkeypatch):
    """The study-scale speed figures: ms per step and episodes per core-hour from a worker pinned to one
    thread, and the parallel efficiency from two real `calnav objectnav` runs (quick: short)."""
    import calnav.eval.bench.agent as bench_agent
    import calnav.eval.bench.backends as bench_backends
    from calnav.eval.bench.context import BenchContext

    ctx = BenchContext(quick=True)
    figures = bench_agent.study_figures(ctx)
    assert figures["objectnav.bench_episodes"] == 1   # the warm-up pass is not counted
    assert 0 < figures["agent.ms_per_step_learned_rgb_160x120"] < 1000
    assert 0 < figures["agent.ms_per_step_first_pass"] < 1000
    assert 0 < figures["objectnav.episodes_per_core_hour"] < 1e6
    monkeypatch.setattr(bench_backends, "QUICK_EFFICIENCY_EPISODES", "100:101")
    eff = bench_backends.parallel_efficiency(ctx)
    assert 0 < eff["backends.parallel_efficiency"] <= 2 and eff["backends.study_1_worker_s"] > 0
    assert 0 < eff["backends.concurrency_ceiling"] <= 2 and eff["backends.study_copies_s"] > 0
    assert eff["backends.efficiency_vs_ceiling"] == eff["backends.parallel_efficiency"] / eff["backends.concurrency_ceiling"]
