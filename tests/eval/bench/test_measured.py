"""The bench figures the docs quote are the committed ``calnav bench`` outputs' rendering."""
from __future__ import annotations

import json
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]


def rosbag_table(runs: list[dict]) -> str:
    """The docs' table of ``sequence.rosbag_*`` figures, one row per ``calnav bench --only
    sequence`` output."""
    rows = ["| run | `sequence.rosbag_vs_folder` | bag ms / frame | folder ms / frame | `sequence.rosbag_raw_vs_folder` |",
            "|---|---|---|---|---|"]
    for n, r in enumerate(runs, 1):
        rows.append(f"| {n} | {r['sequence.rosbag_vs_folder']:.3f} | {r['sequence.rosbag_read_map_ms_640x480']:.1f} | "
                    f"{r['sequence.folder_read_map_ms_640x480']:.1f} | {r['sequence.rosbag_raw_vs_folder']:.3f} |")
    return "\n".join(rows)


def test_the_rosbag_figures_in_the_docs_are_the_committed_runs():
    files = sorted((REPO / "docs" / "measured" / "sequence").glob("run_*.json"))
    runs = [json.loads(f.read_text()) for f in files]
    assert len(runs) >= 3
    text = (REPO / "docs" / "sequences.md").read_text()
    table = re.search(r"<!-- rosbag figures -->\n(.*?)\n\n", text, re.S).group(1)
    assert table == rosbag_table(runs)
    worst = max(r["sequence.rosbag_vs_folder"] for r in runs)
    assert f"costs {round(100 * (min(r['sequence.rosbag_vs_folder'] for r in runs) - 1))}-{round(100 * (worst - 1))} % more" in text
