"""eval.objectnav.compare and eval.stats.paired_difference: hand-computed paired differences, the
comparison of separately made run directories, and its errors."""
import argparse
import csv
import json
import math

import pytest
import yaml

from calnav.eval.objectnav.compare import cell_value, differing_keys, main_compare
from calnav.eval.results_dir import ResultsError, flatten
from calnav.eval.config import ConfigError
from calnav.eval.stats import failure_modes, paired_difference


def _rec(i, success, spl, status="ok"):
    return {"index": i, "category": "bed", "success": success, "spl": spl, "softspl": spl,
            "distance_to_goal": 0.0 if success else 1.0, "status": status}


def test_paired_difference_hand_computed():
    a = [_rec(0, 1.0, 0.5), _rec(1, 0.0, 0.0), _rec(2, 1.0, 0.8), _rec(9, 1.0, 1.0)]
    b = [_rec(2, 1.0, 0.6), _rec(0, 1.0, 0.9), _rec(1, 1.0, 0.7), _rec(5, 0.0, 0.0)]
    # matched indices 0, 1, 2: SPL diffs 0.4, 0.7, -0.2 -> mean 0.3, std(ddof=1) = sqrt(0.21)
    d, sem, n = paired_difference(a, b, "spl")
    assert n == 3
    assert d == pytest.approx(0.3)
    assert sem == pytest.approx(math.sqrt(0.21) / math.sqrt(3))
    # an episode that crashed (or has a non-finite metric) is a failure, as summarize scores it:
    # Success / SPL 0 in the pairs (a run that crashes on the hard episodes is not flattered);
    # DistanceToGoal pairs only the episodes both runs finished
    b_crash = [_rec(0, 1.0, 0.9), _rec(1, 1.0, 0.7), {"index": 2, "status": "error", "category": "bed"}]
    for m in ("success", "spl"):
        assert paired_difference(a, b_crash, m)[2] == 3
    d, _, n = paired_difference(a, b_crash, "success")   # 1 - 1, 1 - 0, 0 - 1
    assert (d, n) == (pytest.approx(0.0), 3)
    assert paired_difference(a, b_crash, "distance_to_goal")[2] == 2
    b_nan = [_rec(0, 1.0, float("nan")), _rec(1, 1.0, 0.7)]   # episode 0: an error record, scored 0
    assert paired_difference(a, b_nan, "success") == (pytest.approx(0.0), pytest.approx(1.0), 2)
    assert paired_difference(a, b_nan, "distance_to_goal")[2] == 1


def test_failure_modes_counts():
    scores = {"spl": 0.0, "softspl": 0.0, "distance_to_goal": 1.0}
    recs = [{"success": 1.0, "steps": 500, "status": "ok"},          # success on the forced STOP
            {"success": 0.0, "steps": 120, "status": "ok"},          # false STOP
            {"success": 0.0, "steps": 500, "status": "ok"},          # out of steps
            {"success": 0.0, "steps": 499, "status": "ok"},          # STOP one step before the limit
            {"index": 4, "status": "error"},
            {"success": 1.0, "steps": 80, "status": "ok", "steps_at_goal": 21},   # lingered, then stopped
            {"success": 0.0, "steps": 500, "status": "ok", "steps_at_goal": 20}]  # at the limit: not lingering
    recs = [{**scores, **r} if r["status"] == "ok" else r for r in recs]
    assert failure_modes(recs, 500) == {"false_stop": 2, "timeout": 2, "crashed": 1, "lingered": 1}
    recs[2]["distance_to_goal"] = math.inf   # a non-finite metric: an error record, counted as crashed
    assert failure_modes(recs, 500) == {"false_stop": 2, "timeout": 1, "crashed": 2, "lingered": 1}


def test_flatten_and_differing_keys():
    assert flatten({"a": {"b": 1, "c": [1, 2]}, "d": "x"}) == {"a.b": 1, "a.c": [1, 2], "d": "x"}
    cfgs = [{"a.b": 1, "run.output_dir": "x", "e": 2}, {"a.b": 2, "run.output_dir": "y", "e": 2, "f": 0}]
    assert differing_keys(cfgs) == ["a.b", "f"]


def test_cell_values():
    assert cell_value({"env.resolution": [640, 480]}, "env.resolution") == "640x480"
    assert cell_value({"agent.map_type": "ndf", "mapping.fusion": "rbu"}, "mapping.fusion") == "-"
    assert cell_value({"agent.goal_threshold": 0.7}, "agent.goal_threshold") == "0.7"
    assert cell_value({}, "agent.segmenter") == "-"


def _run_dir(path, cfg, records):
    path.mkdir(parents=True)
    (path / "config.yaml").write_text(yaml.safe_dump(cfg))
    (path / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    return str(path)


def test_compare_run_directories(tmp_path, capsys):
    base = {"agent": {"map_type": "fused", "segmenter": "gt", "goal_threshold": 0.7},
            "mapping": {"fusion": "rbu"}, "run": {"output_dir": "a"}}
    ndf = {"agent": {"map_type": "ndf", "segmenter": "gt", "goal_threshold": 0.9},
           "mapping": {"fusion": "averaging"}, "run": {"output_dir": "b"}}
    r0 = _run_dir(tmp_path / "rbu", base, [_rec(0, 1.0, 0.5), _rec(1, 1.0, 1.0)])
    r1 = _run_dir(tmp_path / "ndf", ndf, [_rec(0, 0.0, 0.0), _rec(1, 1.0, 0.5)])
    out = tmp_path / "cmp"
    main_compare(argparse.Namespace(runs=[r0, r1], keys="", baseline="0", output=str(out)))
    md = (out / "comparison.md").read_text().splitlines()
    assert md[0] == "| Threshold | Map type | Fusion | SPL | Success | SoftSPL | DTG | N |"
    assert md[2] == "| 0.7 | fused | rbu | 0.750 (0.250) | 1.000 (0.000) | 0.750 (0.250) | 0.000 (0.000) | 2 |"
    assert md[3].startswith("| 0.9 | ndf | - |")  # ndf runs do not use mapping.*
    with open(out / "paired.csv") as f:
        row = next(csv.DictReader(f))
    assert float(row["spl"]) == pytest.approx(-0.5) and float(row["spl_sem"]) == pytest.approx(0.0)
    assert float(row["success"]) == pytest.approx(-0.5) and row["n"] == "2"
    assert row["spl_z"] == "inf" and float(row["success_z"]) == pytest.approx(1.0)  # 0.5 / 0.5
    assert "Paired differences" in capsys.readouterr().out
    failures = (out / "failures.md").read_text().splitlines()
    assert failures[3].endswith("| 1 | 1 | 0 | 0 | 0 | - | 2 |")  # ndf: episode 0 failed with steps absent -> false STOP


def test_compare_of_one_config_twice_names_the_runs(tmp_path):
    """Two runs of the same config (a reproducibility check) differ in no key: the table's
    first column is then the run directory, so its rows can be told apart."""
    cfg = {"agent": {"map_type": "fused", "segmenter": "gt"}, "mapping": {"fusion": "rbu"}}
    r0 = _run_dir(tmp_path / "first", cfg, [_rec(0, 1.0, 0.5), _rec(1, 1.0, 1.0)])
    r1 = _run_dir(tmp_path / "second", cfg, [_rec(0, 0.0, 0.0), _rec(1, 1.0, 0.5)])
    out = tmp_path / "cmp"
    main_compare(argparse.Namespace(runs=[r0, r1], keys="", baseline="0", output=str(out)))
    md = (out / "comparison.md").read_text().splitlines()
    assert md[0] == "| Run | SPL | Success | SoftSPL | DTG | N |"
    assert md[2].startswith(f"| {r0} | 0.750 (0.250) |") and md[3].startswith(f"| {r1} | 0.250 (0.250) |")
    with open(out / "comparison.csv") as f:
        assert [row["Run"] for row in csv.DictReader(f)] == [r0, r1]


def test_paired_identical_runs_render_dash(tmp_path):
    cfg = {"agent": {"map_type": "fused", "segmenter": "gt"}, "mapping": {"fusion": "rbu"}}
    recs = [_rec(0, 1.0, 0.5), _rec(1, 0.0, 0.0)]
    r0 = _run_dir(tmp_path / "a", cfg, recs)
    r1 = _run_dir(tmp_path / "b", {**cfg, "mapping": {"fusion": "glfs"}}, recs)
    out = tmp_path / "cmp"
    main_compare(argparse.Namespace(runs=[r0, r1], keys="", baseline="0", output=str(out)))
    paired = (out / "paired.md").read_text()
    row = next(line for line in paired.splitlines() if line.startswith(f"| {r1} "))
    assert row.endswith("| +0.000 (0.000, -) | +0.000 (0.000, -) | - | - | 2 |")  # 0 / 0 is not a z; no house named
    assert "identical on every paired episode" in paired
    with open(out / "paired.csv") as f:
        assert next(csv.DictReader(f))["spl_z"] == "nan"  # the CSV keeps the number


def test_paired_z_is_judged_by_the_larger_of_episode_and_house_sem(tmp_path):
    """Success differences [1, 1, 1, 1, 0, 0], the 1s in house A: episode SEM 0.2108, house
    (CR1) SEM 0.4444 (tests/eval/objectnav/test_study_report.py works both by hand): |d| / SEM
    is 2/3 / 0.4444 = 1.5, not the 3.16 the episode SEM alone gives."""
    cfg = {"agent": {"map_type": "fused", "segmenter": "gt"}, "mapping": {"fusion": "rbu"}}
    rec = lambda i, v: {**_rec(i, v, v), "scene": "AAAABB"[i]}
    r0 = _run_dir(tmp_path / "a", cfg, [rec(i, 0.0) for i in range(6)])
    r1 = _run_dir(tmp_path / "b", {**cfg, "mapping": {"fusion": "glfs"}}, [rec(i, float(i < 4)) for i in range(6)])
    out = tmp_path / "cmp"
    main_compare(argparse.Namespace(runs=[r0, r1], keys="", baseline="0", output=str(out)))
    with open(out / "paired.csv") as f:
        row = next(csv.DictReader(f))
    assert float(row["success_sem"]) == pytest.approx(0.21082, abs=1e-4)
    assert float(row["success_house_sem"]) == pytest.approx(4 / 9)
    assert float(row["success_z"]) == pytest.approx(1.5)
    assert "| +0.667 (0.211, 0.444) | 1.5 | 1.5 | 6 |" in (out / "paired.md").read_text()


def test_compare_bad_input(tmp_path):
    cfg = {"agent": {"segmenter": "gt"}}
    r0 = _run_dir(tmp_path / "a", cfg, [_rec(0, 1.0, 1.0)])
    r1 = _run_dir(tmp_path / "b", cfg, [_rec(0, 1.0, 1.0)])
    args = dict(runs=[r0, r1], keys="", baseline="0", output=str(tmp_path / "o"))
    with pytest.raises(ConfigError, match="at least two"):
        main_compare(argparse.Namespace(**{**args, "runs": [r0]}))
    with pytest.raises(FileNotFoundError, match="not a calnav objectnav run"):
        main_compare(argparse.Namespace(**{**args, "runs": [r0, str(tmp_path)]}))
    with pytest.raises(ConfigError, match="not in any run's config"):
        main_compare(argparse.Namespace(**{**args, "keys": "agent.nope"}))
    with pytest.raises(ConfigError, match="not a run position"):
        main_compare(argparse.Namespace(**{**args, "baseline": "5"}))


def test_compare_refuses_runs_without_shared_episodes(tmp_path, capsys):
    """Disjoint episode ranges give no paired difference: a clear error, never '+nan (nan)'."""
    cfg = {"agent": {"segmenter": "gt"}, "mapping": {"fusion": "rbu"}}
    r0 = _run_dir(tmp_path / "a", cfg, [_rec(0, 1.0, 1.0), _rec(1, 0.0, 0.0)])
    r1 = _run_dir(tmp_path / "b", {**cfg, "mapping": {"fusion": "glfs"}}, [_rec(2, 1.0, 0.5), _rec(3, 1.0, 0.5)])
    out = tmp_path / "cmp"
    with pytest.raises(ConfigError, match=r"episodes 2:4\) shares no episodes with the baseline .*episodes 0:2"):
        main_compare(argparse.Namespace(runs=[r0, r1], keys="", baseline="0", output=str(out)))
    assert "nan" not in capsys.readouterr().out
    assert not (out / "paired.md").exists()


def test_compare_counts_a_duplicated_episode_once(tmp_path, capsys):
    cfg = {"agent": {"segmenter": "gt"}, "mapping": {"fusion": "rbu"}}
    recs = [_rec(0, 1.0, 1.0), _rec(1, 0.0, 0.0)]
    r0 = _run_dir(tmp_path / "a", cfg, recs + [_rec(1, 0.0, 0.0)])  # episode 1 twice, the same result: once
    r1 = _run_dir(tmp_path / "b", {**cfg, "mapping": {"fusion": "glfs"}}, recs)
    main_compare(argparse.Namespace(runs=[r0, r1], keys="", baseline="0", output=str(tmp_path / "cmp")))
    md = (tmp_path / "cmp" / "comparison.md").read_text().splitlines()
    assert md[2] == "| rbu | 0.500 (0.500) | 0.500 (0.500) | 0.500 (0.500) | 0.500 (0.500) | 2 |"
    assert "1 duplicate record(s) of episode(s) 1" in capsys.readouterr().err


def test_compare_refuses_two_different_records_of_one_episode(tmp_path):
    cfg = {"agent": {"segmenter": "gt"}, "mapping": {"fusion": "rbu"}}
    recs = [_rec(0, 1.0, 1.0), _rec(1, 0.0, 0.0)]
    r0 = _run_dir(tmp_path / "a", cfg, recs + [_rec(1, 1.0, 0.5)])  # episode 1: a failure and a success
    r1 = _run_dir(tmp_path / "b", {**cfg, "mapping": {"fusion": "glfs"}}, recs)
    with pytest.raises(ResultsError, match=rf"^{r0}: episode 1 has two different records \(episodes.jsonl lines 2 and 3"):
        main_compare(argparse.Namespace(runs=[r0, r1], keys="", baseline="0", output=str(tmp_path / "cmp")))
    assert not (tmp_path / "cmp" / "comparison.md").exists()


def test_compare_excludes_crashed_episodes_from_the_pairs(tmp_path, capsys):
    """A baseline whose only shared episode crashed printed '+1.000 (0.000) ... inf': a run with
    no episode finished in both is refused in one line; otherwise a crash pairs as a failure
    (Success / SPL 0), and the SEM is never inf."""
    cfg = {"agent": {"segmenter": "gt"}, "mapping": {"fusion": "rbu"}}
    crashed = {"index": 0, "status": "error", "error": "RuntimeError: boom"}
    r0 = _run_dir(tmp_path / "a", cfg, [crashed])
    r1 = _run_dir(tmp_path / "b", {**cfg, "mapping": {"fusion": "glfs"}}, [_rec(0, 1.0, 1.0)])
    out = tmp_path / "cmp"
    with pytest.raises(ConfigError, match=rf"^{r1} and the baseline {r0} share 1 episode\(s\), none of which finished "
                                          r"in both runs .*no paired difference exists"):
        main_compare(argparse.Namespace(runs=[r0, r1], keys="", baseline="0", output=str(out)))
    assert not (out / "paired.md").exists()
    r2 = _run_dir(tmp_path / "c", cfg, [crashed, _rec(1, 0.0, 0.0)])
    r3 = _run_dir(tmp_path / "d", {**cfg, "mapping": {"fusion": "glfs"}}, [_rec(0, 1.0, 1.0), _rec(1, 0.0, 0.0)])
    main_compare(argparse.Namespace(runs=[r2, r3], keys="", baseline="0", output=str(out)))
    row = next(line for line in (out / "paired.md").read_text().splitlines() if line.startswith(f"| {r3} "))
    assert row.endswith("| +0.500 (0.500, -) | +0.500 (0.500, -) | 1.0 | 1.0 | 2 |")   # episode 0: 0 -> 1
    assert "inf" not in capsys.readouterr().out
    failures = (out / "failures.md").read_text().splitlines()
    assert failures[2].startswith(f"| {r2} | 2 |") and "| 1 | 0 |" in failures[2]   # the crash counts as failed


def test_runs_on_other_episodes_under_the_same_indices_are_not_paired(tmp_path, capsys):
    # Another house style (or scan settings) regenerates the episodes: index 0 names another
    # start, which the records' geodesic distance tells apart. Pairing them would compare
    # different episodes as if they were one.
    cfg = {"agent": {"map_type": "fused", "segmenter": "gt"}, "env": {"dataset": {"style": "clean"}}}
    same = [{**_rec(i, 1.0, 0.5), "episode_id": f"h:{i:03d}", "geodesic_distance": 3.0 + i} for i in range(2)]
    other = [{**_rec(i, 0.0, 0.0), "episode_id": f"h:{i:03d}", "geodesic_distance": 7.5 + i} for i in range(2)]
    r0 = _run_dir(tmp_path / "clean", cfg, same)
    r1 = _run_dir(tmp_path / "scanned", {**cfg, "env": {"dataset": {"style": "scanned"}}}, other)
    r2 = _run_dir(tmp_path / "clean_glfs", {**cfg, "mapping": {"fusion": "glfs"}}, same)
    out = tmp_path / "cmp"
    main_compare(argparse.Namespace(runs=[r0, r1, r2], keys="", baseline="0", output=str(out)))
    paired = (out / "paired.md").read_text()
    row = next(line for line in paired.splitlines() if line.startswith(f"| {r1} "))
    assert row == f"| {r1} | - | - | - | - | 0 (other episodes) |"
    assert "no paired difference exists" in paired
    assert next(line for line in paired.splitlines() if line.startswith(f"| {r2} ")).endswith("| 2 |")


def test_false_stop_rate_is_paired_against_the_baseline(tmp_path):
    """False-STOP indicators (steps 100 < the 500-step limit, failed: a false STOP; 500 steps:
    out of steps): baseline [1, 0, 1, 0] in houses A A B B, run [0, 0, 1, 0] with episode 3
    out of steps. Differences [-1, 0, 0, 0]: mean -0.25, episode SEM sqrt(0.25) / 2 = 0.25; house
    sums (S_g - n_g m) = (-1 + 0.5, 0 + 0.5): CR1 sqrt(2 * 0.5) / 4 = 0.25. A crashed episode is
    no decision: it leaves the pairs."""
    cfg = {"agent": {"segmenter": "gt"}, "mapping": {"fusion": "rbu"}, "env": {"max_episode_steps": 500}}
    rec = lambda i, steps, success=0.0: {**_rec(i, success, success), "steps": steps, "scene": "AABBB"[i]}
    crashed = {"index": 4, "status": "error", "error": "RuntimeError: boom", "scene": "B"}
    r0 = _run_dir(tmp_path / "a", cfg, [rec(0, 100), rec(1, 80, 1.0), rec(2, 100), rec(3, 90, 1.0), rec(4, 100)])
    r1 = _run_dir(tmp_path / "b", {**cfg, "mapping": {"fusion": "glfs"}},
                  [rec(0, 500), rec(1, 80, 1.0), rec(2, 100), rec(3, 500), crashed])
    out = tmp_path / "cmp"
    main_compare(argparse.Namespace(runs=[r0, r1], keys="", baseline="0", output=str(out)))
    failures = (out / "failures.md").read_text()
    assert f"False-STOP rate, run minus {r0}" in failures
    assert f"| {r1} | -0.250 (0.250, 0.250) | 1.0 | 4 |" in failures.splitlines()
