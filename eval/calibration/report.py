"""Writing the map-calibration study's results: ``results.csv`` (one row per segmenter x
strategy x calibration), ``results.md`` (the same as Markdown tables, one per segmenter, and
the GLFS pick), ``glfs_pick.json``, the paper's Fig. 4 (``calibration_vs_accuracy.png``), the
GLFS trade-off curve (``glfs_tradeoff.png``), reliability diagrams of RBU against GLFS per
segmenter (``reliability_<segmenter>.png``, per class ``reliability_classes_<segmenter>.png``),
confidence histograms of correct vs wrong voxels (``error_vs_confidence_<segmenter>.png``) and
the mECE-vs-temperature curves (``tau_curve.csv`` / ``.png``).

mIoU columns: ``miou`` is calnav's convention (void voxels left out, mean over the classes in
the ground truth); ``miou_authors`` the authors' release (``mapping.metrics``: void voxels
predicted as c are false positives of c, classes labelled or predicted). mECE is the same in
both (bins conditioned on the ground-truth class, mean over the classes present).

The GLFS pick (the paper's claim made a rule): among the GLFS variants whose test mIoU is within
``SHIP_TOLERANCE_POINTS`` of the best fixed (strategy, calibration) row, the lowest mECE."""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from calnav.common.atomic import atomic_path, undefined_as_null, write_json_atomic

COLUMNS = ("segmenter", "strategy", "calibration", "miou", "miou_authors", "ece", "tl_ece", "mece", "brier",
           "pixel_mece", "n_voxels")
METRIC_COLUMNS = COLUMNS[3:10]
SHIP_TOLERANCE_POINTS = 0.5   # a GLFS variant may lose at most this many mIoU points to the best fixed row
ERROR_PLOT_FIXED = (("rbu", "none"), ("rbu", "temperature_3d"), ("averaging", "none"),
                    ("geometric_mean", "temperature_3d"))   # fixed rows beside the GLFS variants


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


def _reliability_tables(stats: dict, glfs_variant: str | None = None) -> dict:
    """The maps compared in the reliability figures: RBU raw, RBU after 3D temperature scaling,
    and GLFS (the picked variant, else ``learned``), whichever exist."""
    v = glfs_variant or "learned"
    chosen = {("rbu", "none"): "RBU", ("rbu", "temperature_3d"): "RBU + 3D temperature", ("glfs", v): f"GLFS {v}"}
    return {label: stats[key].reliability() for key, label in chosen.items() if key in stats and stats[key].n}


def glfs_pick(rows: list[dict], tolerance_points: float = SHIP_TOLERANCE_POINTS) -> dict[str, dict]:
    """Per segmenter: the best fixed row by mIoU, the GLFS variants within ``tolerance_points``
    of it, the pick (lowest mECE among those; None if none qualifies) and the lowest-mECE row of
    any kind within the same tolerance (does the pick also beat the fixed rows?)."""
    out = {}
    for seg in dict.fromkeys(r["segmenter"] for r in rows):
        mine = [r for r in rows if r["segmenter"] == seg and math.isfinite(float(r["miou"]))]
        fixed = [r for r in mine if r["strategy"] != "glfs"]
        glfs = [r for r in mine if r["strategy"] == "glfs"]
        if not fixed or not glfs:
            continue
        best = max(fixed, key=lambda r: r["miou"])
        floor = best["miou"] - tolerance_points / 100.0
        ok = [r for r in glfs if r["miou"] >= floor]
        pick = min(ok, key=lambda r: r["mece"]) if ok else None
        lowest = min((r for r in mine if r["miou"] >= floor), key=lambda r: r["mece"])
        out[seg] = {"best_fixed": f"{best['strategy']}/{best['calibration']}", "best_fixed_miou": best["miou"],
                    "tolerance_points": tolerance_points,
                    "variants_within": [r["calibration"] for r in ok],
                    "pick": pick["calibration"] if pick else None,
                    "pick_miou": pick["miou"] if pick else None, "pick_mece": pick["mece"] if pick else None,
                    "lowest_mece_within": f"{lowest['strategy']}/{lowest['calibration']}",
                    "lowest_mece_within_value": lowest["mece"]}
    return out


def _pick_text(picks: dict[str, dict]) -> list[str]:
    lines = [f"## GLFS pick (within {SHIP_TOLERANCE_POINTS:g} mIoU points of the best fixed row, lowest mECE)", ""]
    for seg, p in picks.items():
        if p["pick"]:
            lines.append(f"- {seg}: best fixed {p['best_fixed']} mIoU {p['best_fixed_miou']:.4f}; pick glfs/{p['pick']} "
                         f"(mIoU {p['pick_miou']:.4f}, mECE {p['pick_mece']:.4f}); lowest mECE of any row within the "
                         f"tolerance: {p['lowest_mece_within']} ({p['lowest_mece_within_value']:.4f})")
        else:
            lines.append(f"- {seg}: best fixed {p['best_fixed']} mIoU {p['best_fixed_miou']:.4f}; no GLFS variant is "
                         f"within {p['tolerance_points']:g} points")
    return lines + [""]


def error_tables(stats: dict) -> dict:
    """{label: (edges, correct (B,), wrong (B,), mean confidence of the wrong)} for the
    error-vs-confidence plot: ``ERROR_PLOT_FIXED`` rows and every GLFS variant."""
    keys = [k for k in ERROR_PLOT_FIXED if k in stats] + [k for k in stats if k[0] == "glfs"]
    out = {}
    for s, c in keys:
        st = stats[(s, c)]
        if not st.n:
            continue
        correct, wrong, wrong_conf = st.error_bins()
        out[f"{s} / {c}"] = (np.linspace(0.0, 1.0, st.n_bins + 1), correct, wrong,
                             float(wrong_conf.sum() / max(wrong.sum(), 1)))
    return out


def write_report(out: Path, rows: list[dict], stats_by_segmenter: dict, class_names,
                 glfs_histories: dict | None = None) -> dict[str, dict]:
    """Write CSV, Markdown and plots for ``rows`` (all segmenters so far); ``glfs_histories``
    {segmenter: {variant: TrainHistory.to_dict()}} for the trade-off plot. Returns the GLFS pick."""
    from calnav.eval.calibration.plots import (plot_calibration_vs_accuracy, plot_error_vs_confidence, plot_glfs_tradeoff,
                                        plot_reliability, plot_reliability_per_class)

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
    picks = glfs_pick(rows)
    if picks:
        parts += _pick_text(picks)
        write_json_atomic(out / "glfs_pick.json", undefined_as_null(picks), indent=1)
        plot_glfs_tradeoff(rows, glfs_histories or {}, out / "glfs_tradeoff.png", SHIP_TOLERANCE_POINTS)
    (out / "results.md").write_text("\n".join(parts))
    plot_calibration_vs_accuracy(rows, out / "calibration_vs_accuracy.png",
                                 title="mIoU vs calibration error of the fused test maps")
    for seg, stats in stats_by_segmenter.items():
        tables = _reliability_tables(stats, picks.get(seg, {}).get("pick"))
        if tables:
            plot_reliability(tables, out / f"reliability_{seg}.png", title=f"test voxels, {seg}")
            plot_reliability_per_class(tables, class_names, out / f"reliability_classes_{seg}.png")
        errors = error_tables(stats)
        if errors:
            plot_error_vs_confidence(errors, out / f"error_vs_confidence_{seg}.png",
                                     title=f"confidence of correct vs wrong test voxels, {seg}")
    return picks
