"""`calnav tune`: selection logic on hand-made rows, grid validation, and a tiny end-to-end tune
(2 thresholds x 1 min area on 1 episode) that writes tune.csv and a loadable best.yaml."""
import csv
import math

import pytest

from calnav.eval.cli import main
from calnav.eval.config import ConfigError, load_config
from calnav.eval.objectnav.tune import edge_extension, parse_min_areas, parse_thresholds, point_name, select_best

# A tiny, fast peanut set-up: low resolution, one small house, short episodes.
SMALL = ["env.resolution=64x48", "env.dataset.val_scenes=1", "env.dataset.episodes_per_scene=2",
         "env.max_episode_steps=15", "agent.map_resolution=32x24", "agent.map_size_m=16",
         "mapping.initial_alloc_mb=32", "run.workers=1"]


def _row(t, a, success, spl):
    return {"threshold": t, "min_area": a, "success": success, "spl": spl, "softspl": spl}


def test_select_best_by_metric_and_tie_breaks():
    rows = [_row(0.5, 4, 0.6, 0.30), _row(0.7, 4, 0.5, 0.40), _row(0.9, 4, 0.7, 0.35)]
    assert select_best(rows, "spl")["threshold"] == 0.7
    assert select_best(rows, "success")["threshold"] == 0.9
    # equal SPL: higher success wins, regardless of threshold order
    tied = [_row(0.6, 2, 0.4, 0.5), _row(0.8, 2, 0.6, 0.5), _row(0.7, 2, 0.5, 0.5)]
    assert select_best(tied, "spl")["threshold"] == 0.8
    # equal SPL and success: the lower threshold wins, then the smaller min area
    tied = [_row(0.8, 8, 0.5, 0.5), _row(0.6, 8, 0.5, 0.5), _row(0.6, 2, 0.5, 0.5), _row(0.9, 1, 0.5, 0.5)]
    best = select_best(tied, "spl")
    assert (best["threshold"], best["min_area"]) == (0.6, 2)
    # a NaN metric (no scored episodes) never wins
    assert select_best([_row(0.5, 2, math.nan, math.nan), _row(0.9, 2, 0.0, 0.0)], "spl")["threshold"] == 0.9
    with pytest.raises(ConfigError, match="empty grid"):
        select_best([], "spl")
    with pytest.raises(ConfigError, match="valid: spl"):
        select_best(rows, "dtg")


def test_grid_parsing_and_validation():
    assert parse_thresholds("0.9, 0.5,0.5,1") == [0.5, 0.9, 1.0]
    assert parse_min_areas("8,2") == [2, 8]
    assert point_name(0.8, 4) == "0.8_4"
    for bad in ("0", "1.2", "-0.1"):
        with pytest.raises(ConfigError, match=r"\(0, 1\]"):
            parse_thresholds(bad)
    with pytest.raises(ConfigError, match=">= 1"):
        parse_min_areas("2,0")
    with pytest.raises(ConfigError, match="empty"):
        parse_thresholds(" , ")


def test_edge_extension():
    assert edge_extension({0.5: 0.3, 0.7: 0.4, 0.9: 0.35}) is None   # interior: the grid brackets it
    assert edge_extension({0.5: 0.3, 0.7: 0.4, 0.9: 0.45}) == 0.95   # halfway to 1
    assert edge_extension({0.7: 0.4, 0.9: 0.45, 0.95: 0.5}) == 0.975
    assert edge_extension({0.5: 0.5, 0.7: 0.4, 0.9: 0.3}) == pytest.approx(0.3)  # one spacing below
    assert edge_extension({0.2: 0.5, 0.7: 0.4}) is None              # 0.2 - 0.5 <= 0
    assert edge_extension({1.0: 0.5}) is None and edge_extension({0.5: 0.5}) == 0.75
    # a flat optimum (equal up to float noise) is not extended, and ties go to the lower threshold
    flat = {0.5: 0.5945951766802705, 0.7: 0.5945951766802706, 0.85: 0.5945951766802705}
    assert edge_extension(flat) is None
    assert edge_extension({0.5: 0.4, 0.7: 0.5, 0.9: 0.5}) is None
    # ranked as select_best ranks (SPL, then Success): an SPL tie that Success breaks at the
    # top edge extends, as select_best would pick that edge
    assert edge_extension({0.7: (0.5, 0.6), 0.9: (0.5, 0.7)}) == 0.95
    assert select_best([{"threshold": 0.7, "min_area": 4, "spl": 0.5, "success": 0.6},
                        {"threshold": 0.9, "min_area": 4, "spl": 0.5, "success": 0.7}])["threshold"] == 0.9


def test_select_best_ignores_float_noise():
    rows = [{"threshold": t, "min_area": 4, "spl": v, "success": 0.95}
            for t, v in ((0.5, 0.5945951766802705), (0.7, 0.5945951766802706))]
    assert select_best(rows, "spl")["threshold"] == 0.5


def test_tune_bad_input_exits_2(tmp_path, capsys):
    base = ["tune", "--episodes", "0:1", "--output", str(tmp_path / "t"), *SMALL]
    assert main(base + ["--thresholds", "0.5,1.5"]) == 2
    assert "(0, 1]" in capsys.readouterr().err
    assert main(base + ["--min-areas", "0"]) == 2
    assert ">= 1" in capsys.readouterr().err
    assert main(base + ["--thresholds", ""]) == 2
    assert "empty" in capsys.readouterr().err
    assert main(base + ["agent.goal_threshold=0.7"]) == 2
    assert "is tuned by" in capsys.readouterr().err
    assert main(base + ["--extend", "-1"]) == 2
    assert ">= 0" in capsys.readouterr().err
    assert main(base + ["run.agent=oracle"]) == 2  # the oracle has no goal detection to tune
    assert "run.agent is 'oracle'" in capsys.readouterr().err
    # an uncertainty-aware agent at a grid threshold <= agent.uncertain_low has nothing to verify
    assert main(base + ["--thresholds", "0.3,0.5", "agent.uncertainty_aware=true"]) == 2
    assert "uncertain_low (0.3) must be below agent.goal_threshold (0.3)" in capsys.readouterr().err
    assert not (tmp_path / "t").exists()  # nothing ran


@pytest.mark.e2e
def test_tune_end_to_end_writes_csv_and_loadable_best(tmp_path, capsys):
    out = tmp_path / "tune"
    args = ["tune", "--episodes", "0:1", "--thresholds", "0.9,0.6", "--min-areas", "3",
            "--output", str(out), *SMALL]
    assert main(args) == 0
    printed = capsys.readouterr().out
    with open(out / "tune.csv") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["threshold", "min_area", "success", "success_sem", "spl", "spl_sem",
                             "softspl", "dtg", "n"]
    assert [(float(r["threshold"]), int(r["min_area"]), int(r["n"])) for r in rows] == [(0.6, 3, 1), (0.9, 3, 1)]
    for t in ("0.6", "0.9"):
        assert (out / f"{t}_3" / "summary.json").exists()
    expected = select_best([{**r, "threshold": float(r["threshold"]), "min_area": int(r["min_area"]),
                             "spl": float(r["spl"]), "success": float(r["success"])} for r in rows], "spl")

    cfg = load_config(out / "best.yaml")  # a complete, loadable config
    assert cfg.agent.goal_threshold == expected["threshold"]
    assert cfg.agent.goal_min_area_cells == 3
    assert cfg.env.max_episode_steps == 15 and cfg.env.resolution == (64, 48)  # overrides kept
    header = "\n".join(ln for ln in (out / "best.yaml").read_text().splitlines() if ln.startswith("#"))
    assert "episodes 0:1" in header and "by spl" in header
    assert f"agent.goal_threshold={expected['threshold']:g}" in printed

    # rerun resumes: no episode is run again, results unchanged
    before = (out / "0.6_3" / "episodes.jsonl").read_text()
    assert main(args) == 0
    assert (out / "0.6_3" / "episodes.jsonl").read_text() == before

    # --extend 1: with two points the best is on an edge; unless they tie, one threshold beyond it is added
    assert main(args + ["--extend", "1"]) == 0
    with open(out / "tune.csv") as f:
        ts = [float(r["threshold"]) for r in csv.DictReader(f)]
    scores = {float(r["threshold"]): float(r["spl"]) for r in rows}
    nxt = edge_extension(scores)
    assert ts == sorted([0.6, 0.9] + ([nxt] if nxt is not None else []))
    assert (out / "0.6_3" / "episodes.jsonl").read_text() == before


def test_tune_does_not_extend_into_a_refused_threshold(tmp_path, monkeypatch, capsys):
    """Best on the lower edge (0.5) would extend the grid to 0.3, which the uncertainty-aware
    agent refuses (agent.uncertain_low 0.3): the tune stops extending, says why, and writes
    the two points it ran (episodes faked: only the grid logic is under test)."""
    import calnav.eval.objectnav.run as run_mod
    from calnav.eval.objectnav.tune import run_tune

    def fake_run_jobs(jobs, force=False, progress=True):
        return [{"success": 1.0, "success_sem": 0.0, "spl": 1.0 - job.cfg.agent.goal_threshold, "spl_sem": 0.0,
                 "softspl": 0.5, "distance_to_goal": 0.0, "count": 1} for job in jobs]

    monkeypatch.setattr(run_mod, "run_jobs", fake_run_jobs)
    rows, best = run_tune(None, [*SMALL, "agent.uncertainty_aware=true"], "0:1", "0.5,0.7", "4", "spl",
                          tmp_path / "t", extend=2)
    assert [r["threshold"] for r in rows] == [0.5, 0.7] and best["threshold"] == 0.5
    assert "not extending to goal_threshold=0.3" in capsys.readouterr().out
    assert (tmp_path / "t" / "tune.csv").read_text().count("\n") == 3
