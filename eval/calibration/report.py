"""Writing the map-calibration study's results: ``results.csv`` (one row per segmenter x
strategy x calibration), ``results.md`` (the same as Markdown tables, one per segmenter), the
paper's Fig. 4 (``calibration_vs_accuracy.png``) and reliability diagrams of RBU against GLFS
per segmenter (``reliability_<segmenter>.png``, per class ``reliability_classes_<segmenter>.png``)."""
from __future__ import annotations

import csv
import math
from pathlib import Path

from common.atomic import atomic_path

COLUMNS = ("segmenter", "strategy", "calibration", "miou", "ece", "tl_ece", "mece", "brier", "pixel_mece", "n_voxels")
METRIC_COLUMNS = COLUMNS[3:9]


def _fmt(v) -> str:
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.4f}"
    return str(v)


def format_table(rows: list[dict], markdown: bool = False) -> str:
    """Rows as an aligned text table (or a Markdown table)."""
    cols = COLUMNS
    cells = [[_fmt(r[c]) for c in cols] for r in rows]
    if markdown:
        out = ["| " + " | ".join(cols) + " |", "|" + "|".join("---" if i < 3 else "---:" for i in range(len(cols))) + "|"]
        out += ["| " + " | ".join(c) + " |" for c in cells]
        return "\n".join(out)
    width = [max(len(c), *(len(row[i]) for row in cells)) for i, c in enumerate(cols)]
    line = lambda vals: "  ".join(v.ljust(w) if i < 3 else v.rjust(w) for i, (v, w) in enumerate(zip(vals, width)))  # noqa: E731
    return "\n".join([line(cols), line(["-" * w for w in width])] + [line(c) for c in cells])


def _reliability_tables(stats: dict) -> dict:
    """The maps compared in the reliability figures: RBU raw, RBU after 3D temperature scaling,
    and learned GLFS, whichever exist."""
    chosen = {("rbu", "none"): "RBU", ("rbu", "temperature_3d"): "RBU + 3D temperature", ("glfs", "learned"): "GLFS"}
    return {label: stats[key].reliability() for key, label in chosen.items() if key in stats and stats[key].n}


def write_report(out: Path, rows: list[dict], stats_by_segmenter: dict, class_names) -> None:
    """Write CSV, Markdown and plots for ``rows`` (all segmenters so far)."""
    from eval.calibration.plots import plot_calibration_vs_accuracy, plot_reliability, plot_reliability_per_class

    out.mkdir(parents=True, exist_ok=True)
    with atomic_path(out / "results.csv") as tmp, open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        for r in rows:
            w.writerow({c: (f"{r[c]:.6f}" if isinstance(r[c], float) else r[c]) for c in COLUMNS})
    parts = ["# Map calibration results", "",
             "Voxel metrics on the test houses' fused maps; pixel_mece is the mECE of the segmenter's pixels "
             "with the row's temperature. Produced by `calnav calibrate-map` (config: config.yaml).", ""]
    for seg in dict.fromkeys(r["segmenter"] for r in rows):
        parts += [f"## {seg}", "", format_table([r for r in rows if r["segmenter"] == seg], markdown=True), ""]
    (out / "results.md").write_text("\n".join(parts))
    plot_calibration_vs_accuracy(rows, out / "calibration_vs_accuracy.png",
                                 title="mIoU vs calibration error of the fused test maps")
    for seg, stats in stats_by_segmenter.items():
        tables = _reliability_tables(stats)
        if tables:
            plot_reliability(tables, out / f"reliability_{seg}.png", title=f"test voxels, {seg}")
            plot_reliability_per_class(tables, class_names, out / f"reliability_classes_{seg}.png")
