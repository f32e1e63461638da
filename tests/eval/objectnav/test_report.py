"""eval.objectnav.report: multirun naming, the Table II comparison (md / csv / png) and
per-run plots, on hand-made summaries (no episodes are run)."""
import csv

import pytest

from calnav.eval.config import expand_multirun
from calnav.eval.objectnav.report import (combo_dirname, combo_values, comparison_markdown, plot_run, varied_keys,
                                   write_comparison)
from calnav.eval.stats import summarize


def _rec(cat, success, spl, soft, dtg):
    return {"category": cat, "success": success, "spl": spl, "softspl": soft, "distance_to_goal": dtg,
            "status": "ok"}


def test_varied_keys_and_names():
    overrides = ["mapping.fusion=rbu,glfs", "env.resolution=64x48", "agent.segmenter=gt,noisy", "x.y=[1,2]"]
    assert varied_keys(overrides) == ["mapping.fusion", "agent.segmenter"]
    combos = expand_multirun(overrides)
    assert len(combos) == 4
    values = combo_values(combos[0], varied_keys(overrides))
    assert values == {"mapping.fusion": "rbu", "agent.segmenter": "gt"}
    assert combo_dirname(values) == "mapping.fusion=rbu__agent.segmenter=gt"
    assert combo_dirname({"agent.segmenter_config.weights": "a/b.pt"}) == "agent.segmenter_config.weights=a-b.pt"
    assert combo_dirname({}) == "default"


def test_comparison_table_csv_and_plot(tmp_path):
    a = summarize([_rec("bed", 1.0, 0.5, 0.6, 0.0), _rec("tv_monitor", 0.0, 0.0, 0.2, 2.0)])
    b = summarize([_rec("bed", 1.0, 1.0, 1.0, 0.0)])
    keys = ["agent.map_type", "agent.segmenter"]
    rows = [({"agent.map_type": "fused", "agent.segmenter": "gt"}, a),
            ({"agent.map_type": "ndf", "agent.segmenter": "gt"}, b)]
    md = comparison_markdown(keys, rows)
    lines = md.splitlines()
    assert lines[0] == "| Map type | Segmentation | SPL | Success | SoftSPL | DTG | N |"
    # SPL mean 0.25, SEM = std([0.5, 0]) / sqrt(2) = 0.25; Success 0.5 (0.5); DTG 1.0 (1.0) metres
    assert lines[2] == "| fused | gt | 0.250 (0.250) | 0.500 (0.500) | 0.400 (0.200) | 1.000 (1.000) | 2 |"
    assert lines[3].startswith("| ndf | gt | 1.000 (0.000) |")
    assert write_comparison(keys, rows, tmp_path) == md
    assert (tmp_path / "comparison.md").read_text().strip() == md
    with open(tmp_path / "comparison.csv") as f:
        table = list(csv.DictReader(f))
    assert float(table[0]["spl"]) == pytest.approx(0.25) and float(table[0]["success_sem"]) == pytest.approx(0.5)
    assert float(table[1]["distance_to_goal"]) == 0.0 and table[1]["count"] == "1"
    assert (tmp_path / "comparison.png").stat().st_size > 1000


def test_plot_run_writes_pngs(tmp_path):
    s = summarize([_rec("bed", 1.0, 0.5, 0.6, 0.0), _rec("chair", 0.0, 0.0, 0.2, 2.0)])
    paths = plot_run(s, tmp_path, title="peanut")
    assert [p.name for p in paths] == ["metrics.png", "per_category_success.png"]
    for p in paths:
        assert p.parent == tmp_path / "plots" and p.stat().st_size > 1000


def test_a_non_finite_metric_is_a_failed_episode_not_a_dropped_value(tmp_path):
    """The oracle in a house its episodes are not of ended with SPL NaN and DTG inf; the summary
    dropped the NaN from SPL's mean only (SPL 0.964 above Success 0.667). Such a record is an
    error record: counted in failed, 0 in Success / SPL / SoftSPL like a crash, DTG over the
    finished episodes; every mean is over one set of episodes and the summary is strict JSON."""
    import json
    import math

    from calnav.common.atomic import write_json_atomic
    from calnav.eval.stats import finite_or_error, format_metrics_table

    recs = [_rec("bed", 1.0, 0.95, 0.95, 0.1), _rec("bed", 1.0, 0.98, 0.98, 0.2),
            _rec("chair", 0.0, math.nan, 0.0, math.inf)]
    s = summarize(recs)
    assert (s["count"], s["failed"]) == (3, 1)
    assert s["success"] == pytest.approx(2 / 3) and s["spl"] == pytest.approx((0.95 + 0.98) / 3)
    assert s["spl"] <= s["success"]
    assert s["distance_to_goal"] == pytest.approx(0.15)
    assert s["per_category"]["chair"]["spl"] == 0.0 and s["per_category"]["chair"]["distance_to_goal"] is None
    err = finite_or_error(recs[2])
    assert err["status"] == "error" and "spl" not in err and "distance_to_goal" not in err
    assert err["error"] == "non-finite metrics (spl nan, distance_to_goal inf): an episode without a finite score " \
                           "counts as failed"
    write_json_atomic(tmp_path / "summary.json", s)
    json.loads((tmp_path / "summary.json").read_text(), parse_constant=lambda c: pytest.fail(f"bare {c}"))
    assert "| 0.667 (0.333) | 0.643 (0.322) | 0.643 (0.322) | 0.150 (0.050) | 3 |" in format_metrics_table([("x", s)])
    crashed = summarize([{"index": 0, "status": "error", "error": "boom"}])
    assert crashed["distance_to_goal"] is None and "| 0.000 (0.000) | - | 1 |" in format_metrics_table([("x", crashed)])
    with pytest.raises(ValueError, match=r"summary.json: spl is nan, which JSON cannot hold"):
        write_json_atomic(tmp_path / "summary.json", {**s, "spl": math.nan})
    assert json.loads((tmp_path / "summary.json").read_text())["spl"] == s["spl"]   # left as it was


def test_a_records_file_with_a_nan_metric_reads_as_a_failed_episode(tmp_path):
    """episodes.jsonl written before records were checked (bare NaN / Infinity): read as an
    error record, so the rerun retries it and compare counts it as failed."""
    from calnav.eval.results_dir import RecordsFile, read_records

    path = tmp_path / "episodes.jsonl"
    path.write_text('{"index": 0, "status": "ok", "success": 1.0, "spl": 0.5, "softspl": 0.5, '
                    '"distance_to_goal": 0.1}\n'
                    '{"index": 1, "status": "ok", "success": 0.0, "spl": NaN, "softspl": 0.0, '
                    '"distance_to_goal": Infinity}\n')
    rec = read_records(path).records[1]
    assert rec["status"] == "error" and "non-finite metrics (spl nan, distance_to_goal inf)" in rec["error"]
    kept = RecordsFile(path).resume(retry=lambda r: r.get("status") != "ok")
    assert list(kept.records) == [0] and "NaN" not in path.read_text()
