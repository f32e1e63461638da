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
