"""Reports of `calnav objectnav` runs: per-run plots and the multirun comparison table/plot.

Metrics: Success, SPL, SoftSPL are fractions in [0, 1]; DTG (DistanceToGoal) is in metres.
Every number is reported as mean and SEM (standard error of the mean over episodes,
``eval.stats.mean_sem``); error bars in the plots are +-1 SEM.

- ``plot_run(summary, out)``: ``out/plots/metrics.png`` (Success/SPL/SoftSPL bars) and
  ``out/plots/per_category_success.png`` (Success per goal category).
- ``write_comparison(keys, rows, out)``: ``out/comparison.md`` (Table II layout: the varied
  keys, then SPL, Success, SoftSPL, DTG as "mean (SEM)"), ``out/comparison.csv`` (separate
  mean and sem columns) and ``out/comparison.png`` (grouped bars with SEM error bars).
"""
from __future__ import annotations

import csv
import math
from pathlib import Path

from calnav.eval.stats import METRIC_LABELS, mean_sem_cell

# Table II column order: SPL first, as in the paper.
TABLE_METRICS: tuple[str, ...] = ("spl", "success", "softspl", "distance_to_goal")
PLOT_METRICS: tuple[str, ...] = ("success", "spl", "softspl")  # same unit (fraction), one axis
# Readable column headers for common varied keys; other keys are shown as they are.
KEY_LABELS: dict[str, str] = {"agent.map_type": "Map type", "mapping.fusion": "Fusion",
                              "agent.segmenter": "Segmentation", "agent.uncertainty_aware": "Uncertainty-aware",
                              "agent.semantic_prior": "Semantic prior", "agent.goal_threshold": "Threshold",
                              "agent.goal_min_area_cells": "Min area", "env.resolution": "Resolution",
                              "run.agent": "Agent"}


def varied_keys(overrides: list[str]) -> list[str]:
    """Keys of multirun overrides that take several values ('a=1,2' -> 'a'; a YAML list
    '[1,2]' is one value), in the given order."""
    keys = []
    for text in overrides:
        key, _, raw = text.partition("=")
        if "," in raw and not raw.startswith("["):
            keys.append(key.strip())
    return keys


def combo_values(combo: list[str], keys: list[str]) -> dict[str, str]:
    """{key: value} of the varied ``keys`` within one expanded combination ['a=1', 'b=x']."""
    vals = dict(t.partition("=")[::2] for t in combo)
    return {k: vals[k].strip() for k in keys}


def combo_dirname(values: dict[str, str]) -> str:
    """Readable subdirectory name, e.g. 'mapping.fusion=rbu__agent.segmenter=gt' ('/' -> '-')."""
    name = "__".join(f"{k}={v}" for k, v in values.items()) or "default"
    return name.replace("/", "-").replace(" ", "")


def _cell(s: dict, m: str) -> str:
    return mean_sem_cell(s, m)


def comparison_markdown(keys: list[str], rows: list[tuple[dict[str, str], dict]]) -> str:
    """Markdown table: one row per (values of the varied keys, summary)."""
    heads = [KEY_LABELS.get(k, k) for k in keys] + [METRIC_LABELS[m] for m in TABLE_METRICS] + ["N"]
    lines = ["| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    for values, s in rows:
        cells = [values[k] for k in keys] + [_cell(s, m) for m in TABLE_METRICS] + [str(s["count"])]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_comparison(keys: list[str], rows: list[tuple[dict[str, str], dict]], out: Path) -> str:
    """Write comparison.md / .csv / .png into ``out``; returns the markdown table."""
    out.mkdir(parents=True, exist_ok=True)
    table = comparison_markdown(keys, rows)
    (out / "comparison.md").write_text(table + "\n")
    with open(out / "comparison.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(keys + [c for m in TABLE_METRICS for c in (m, f"{m}_sem")] + ["count"])
        for values, s in rows:
            w.writerow([values[k] for k in keys] + [s[c] for m in TABLE_METRICS for c in (m, f"{m}_sem")]
                       + [s["count"]])
    plot_comparison(keys, rows, out / "comparison.png")
    return table


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _err(v: float) -> float:
    return 0.0 if v is None or not math.isfinite(v) else v


def plot_comparison(keys: list[str], rows: list[tuple[dict[str, str], dict]], path: Path) -> Path:
    """Grouped bars: one group per metric (Success, SPL, SoftSPL), one bar per combination,
    +-1 SEM error bars."""
    import numpy as np

    plt = _plt()
    n = max(1, len(rows))
    width = 0.8 / n
    x = np.arange(len(PLOT_METRICS))
    fig, ax = plt.subplots(figsize=(max(6.0, 1.2 * n + 4), 4))
    for j, (values, s) in enumerate(rows):
        label = ", ".join(f"{KEY_LABELS.get(k, k)}={values[k]}" for k in keys) or "default"
        ax.bar(x + (j - (n - 1) / 2) * width, [_err(s[m]) for m in PLOT_METRICS], width,
               yerr=[_err(s[m + "_sem"]) for m in PLOT_METRICS], capsize=3, label=label)
    ax.set_xticks(x, [METRIC_LABELS[m] for m in PLOT_METRICS])
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("mean (+-1 SEM)")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1))
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_run(summary: dict, out: Path, title: str = "") -> list[Path]:
    """``out/plots/metrics.png`` and ``out/plots/per_category_success.png`` of one run's summary."""
    plt = _plt()
    plots = out / "plots"
    plots.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(4.5, 3.5))
    ax.bar([METRIC_LABELS[m] for m in PLOT_METRICS], [_err(summary[m]) for m in PLOT_METRICS],
           yerr=[_err(summary[m + "_sem"]) for m in PLOT_METRICS], capsize=4, color=["C0", "C1", "C2"])
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("mean (+-1 SEM)")
    ax.set_title(f"{title} (N={summary['count']})".strip())
    p1 = plots / "metrics.png"
    fig.savefig(p1, dpi=100, bbox_inches="tight")
    plt.close(fig)

    cats = summary.get("per_category", {})
    names = list(cats)
    fig, ax = plt.subplots(figsize=(max(4.5, 0.6 * len(names) + 2), 3.5))
    ax.bar(names, [_err(cats[c]["success"]) for c in names],
           yerr=[_err(cats[c]["success_sem"]) for c in names], capsize=4)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("Success (+-1 SEM)")
    ax.set_title("Success per goal category")
    ax.tick_params(axis="x", labelrotation=45)
    p2 = plots / "per_category_success.png"
    fig.savefig(p2, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return [p1, p2]
