"""Calibration figures (matplotlib, "Agg" backend; every function writes a PNG and returns its Path).

- ``plot_reliability``: one column per named ``ReliabilityTable`` (e.g. one per fusion strategy).
  Top row: the reliability diagram -- blue bars are the accuracy of each top-label confidence
  bin (at the bin centre, one bin wide), red translucent bars the gap from accuracy to the
  bin's mean confidence, the dashed diagonal is perfect calibration; ECE / mECE in the title.
  Bottom row: the fraction of samples per bin (log scale), i.e. where the confidences lie.
- ``plot_reliability_per_class``: one subplot per ground-truth class present, with every
  table's per-class accuracy-vs-confidence curve (bins conditioned on the true class, the
  mECE conditioning) and the diagonal; the title lists each table's within-class ECE.
- ``plot_glfs_tradeoff``: mIoU vs mECE of the GLFS variants against the fixed rows, and their
  training checkpoints; ``plot_error_vs_confidence``: confidence histograms of correct vs wrong
  voxels per strategy.
- ``plot_calibration_vs_accuracy``: as in the paper's Fig. 4, mIoU (y) against mECE, TL-ECE and
  Brier (x) for every (segmenter, strategy, calibration) row; marker = fusion strategy, colour
  = calibration method, filled = first segmenter, hollow = the others.

Empty bins (NaN) and NaN metric values are skipped, not drawn.
"""
from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402

from calnav.mapping.metrics import ReliabilityTable  # noqa: E402

STRATEGY_MARKERS = {"rbu": "o", "averaging": "s", "histogram": "^", "geometric_mean": "D", "glfs": "*"}
FALLBACK_MARKER = "X"
CALIBRATION_COLORS = {"none": "tab:gray", "temperature_2d": "tab:blue", "temperature_3d": "tab:orange",
                      "vector_3d": "tab:green", "learned": "tab:purple"}
FALLBACK_COLOR = "black"
X_METRICS = (("mece", "mECE"), ("tl_ece", "TL-ECE"), ("brier", "Brier"))


def _save(fig, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path


def _diagonal(ax) -> None:
    ax.plot([0, 1], [0, 1], "k--", lw=1, label="_nolegend_")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)


def plot_reliability(tables: dict[str, ReliabilityTable], path, title: str = "") -> Path:
    """Reliability diagram (top) and confidence histogram (bottom), one column per table."""
    if not tables:
        raise ValueError("plot_reliability needs at least one table")
    n = len(tables)
    fig, axes = plt.subplots(2, n, figsize=(3.6 * n, 5.2), squeeze=False,
                             gridspec_kw={"height_ratios": [3, 1]}, sharex="col")
    for col, (name, t) in enumerate(tables.items()):
        ax, hax = axes[0, col], axes[1, col]
        centers, width = 0.5 * (t.edges[:-1] + t.edges[1:]), np.diff(t.edges)
        ok = np.isfinite(t.accuracy) & np.isfinite(t.confidence)
        acc, conf = t.accuracy[ok], t.confidence[ok]
        ax.bar(centers[ok], acc, width=width[ok], color="tab:blue", edgecolor="k", lw=0.5, label="accuracy",
               zorder=1)
        ax.bar(centers[ok], conf - acc, bottom=acc, width=width[ok], color="red", alpha=0.3,
               edgecolor="red", lw=0.5, label="gap (to confidence)", zorder=2)
        _diagonal(ax)
        ax.set_title(f"{name}\nECE {t.ece:.3f}  mECE {t.mece:.3f}", fontsize=9)
        if col == 0:
            ax.set_ylabel("accuracy")
            ax.legend(loc="upper left", fontsize=7)
        total = max(int(t.count.sum()), 1)
        frac = t.count / total
        hax.bar(centers[t.count > 0], frac[t.count > 0], width=width[t.count > 0], color="tab:gray")
        if (t.count > 0).any():
            hax.set_yscale("log")
        hax.set_xlabel("confidence")
        if col == 0:
            hax.set_ylabel("fraction")
    if title:
        fig.suptitle(title)
    return _save(fig, path)


def plot_reliability_per_class(tables: dict[str, ReliabilityTable], class_names, path) -> Path:
    """Per-class reliability curves of every table, one subplot per class present."""
    if not tables:
        raise ValueError("plot_reliability_per_class needs at least one table")
    present = np.flatnonzero(sum(t.class_count.sum(axis=1) for t in tables.values()) > 0)
    n = max(len(present), 1)
    ncols = min(4, n)
    nrows = math.ceil(n / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(3.2 * ncols, 3.0 * nrows), squeeze=False)
    eces = {name: t.class_ece() for name, t in tables.items()}
    for i, c in enumerate(present):
        ax = axes.flat[i]
        for name, t in tables.items():
            ok = np.isfinite(t.class_accuracy[c]) & np.isfinite(t.class_confidence[c])
            ax.plot(t.class_confidence[c][ok], t.class_accuracy[c][ok], "o-", ms=3, label=name)
        _diagonal(ax)
        ax.set_xlim(-0.02, 1.02)
        ax.set_ylim(-0.02, 1.02)                    # markers at accuracy 0 / 1 stay visible
        label = class_names[c] if c < len(class_names) else str(c)
        ece_txt = " ".join(f"{name}={eces[name][c]:.2f}" for name in tables if np.isfinite(eces[name][c]))
        ax.set_title(f"{label}\n{ece_txt}", fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in axes.flat[len(present):]:
        ax.axis("off")
    if len(present) == 0:
        axes.flat[0].text(0.5, 0.5, "no samples", ha="center", va="center")
    for ax in axes[:, 0]:
        ax.set_ylabel("accuracy", fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("confidence", fontsize=8)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    handles, labels = axes.flat[0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 6), fontsize=8,
                   bbox_to_anchor=(0.5, 0.0), frameon=False)
    return _save(fig, path)


def plot_calibration_vs_accuracy(rows: list[dict], path, title: str = "") -> Path:
    """mIoU against mECE / TL-ECE / Brier (paper Fig. 4); NaN values are skipped."""
    segmenters = list(dict.fromkeys(str(r.get("segmenter", "")) for r in rows))
    fig, axes = plt.subplots(1, len(X_METRICS), figsize=(4.0 * len(X_METRICS), 3.6), squeeze=False)
    for ax, (key, label) in zip(axes[0], X_METRICS):
        for r in rows:
            x, y = float(r.get(key, math.nan)), float(r.get("miou", math.nan))
            if not (math.isfinite(x) and math.isfinite(y)):
                continue
            color = CALIBRATION_COLORS["learned"] if r.get("strategy") == "glfs" else \
                CALIBRATION_COLORS.get(r.get("calibration"), FALLBACK_COLOR)
            filled = str(r.get("segmenter", "")) == segmenters[0]
            ax.scatter([x], [y], marker=STRATEGY_MARKERS.get(r.get("strategy"), FALLBACK_MARKER), s=45,
                       facecolors=color if filled else "none", edgecolors=color, linewidths=1.2)
        ax.set_xlabel(f"{label} (lower is better)")
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("mIoU")
    strategies = list(dict.fromkeys(r.get("strategy") for r in rows))
    calibrations = list(dict.fromkeys("learned" if r.get("strategy") == "glfs" else r.get("calibration") for r in rows))
    handles = [Line2D([], [], ls="", label="marker = strategy")]
    handles += [Line2D([], [], ls="", marker=STRATEGY_MARKERS.get(s, FALLBACK_MARKER), color="k",
                       mfc="none", label=str(s)) for s in strategies]
    handles += [Line2D([], [], ls="", label="colour = calibration")]
    handles += [Line2D([], [], ls="", marker="s", color=CALIBRATION_COLORS.get(c, FALLBACK_COLOR),
                       label=str(c)) for c in calibrations]
    handles += [Line2D([], [], ls="", label="fill = segmenter")]
    handles += [Line2D([], [], ls="", marker="o", color="k", mfc="k" if i == 0 else "none", label=s)
                for i, s in enumerate(segmenters)]
    fig.legend(handles=handles, loc="center left", bbox_to_anchor=(1.0, 0.5), fontsize=8, frameon=False)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return _save(fig, path)


def plot_glfs_tradeoff(rows: list[dict], histories: dict[str, dict[str, dict]], path,
                       tolerance_points: float = 0.5) -> Path:
    """The accuracy/calibration trade-off of GLFS, one column per segmenter.

    Top: test-map mIoU against mECE of every fixed (strategy, calibration) row (grey, marker =
    strategy) and every GLFS variant (coloured stars, named); the shaded band is within
    ``tolerance_points`` mIoU points of the best fixed row (the shipping rule). Bottom: the
    validation checkpoints of each GLFS variant's training (hard mIoU against mECE, joined in
    training order; the kept one circled), the path each selection rule chooses from.
    """
    segmenters = list(dict.fromkeys(str(r["segmenter"]) for r in rows))
    fig, axes = plt.subplots(2, len(segmenters), figsize=(5.6 * len(segmenters), 8.4), squeeze=False)
    cmap = plt.get_cmap("tab10")
    for col, seg in enumerate(segmenters):
        ax, vax = axes[0, col], axes[1, col]
        mine = [r for r in rows if r["segmenter"] == seg]
        fixed = [r for r in mine if r["strategy"] != "glfs" and math.isfinite(float(r["miou"]))]
        variants = [r for r in mine if r["strategy"] == "glfs"]
        for r in fixed:
            ax.scatter(r["mece"], r["miou"], marker=STRATEGY_MARKERS.get(r["strategy"], FALLBACK_MARKER), s=30,
                       facecolors="none", edgecolors="tab:gray")
        if fixed:
            best = max(float(r["miou"]) for r in fixed)
            ax.axhspan(best - tolerance_points / 100.0, best, color="tab:green", alpha=0.12,
                       label=f"within {tolerance_points:g} pt of best fixed")
        for i, r in enumerate(variants):
            ax.scatter(r["mece"], r["miou"], marker="*", s=140, color=cmap(i % 10), edgecolors="k", lw=0.5,
                       label=f"glfs {r['calibration']}", zorder=3)
        ax.set_xlabel("mECE (test maps, lower is better)")
        ax.set_ylabel("mIoU (test maps)")
        ax.set_title(f"{seg}: GLFS variants (stars) vs fixed rows (grey)", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="lower right")
        for i, r in enumerate(variants):
            h = histories.get(seg, {}).get(str(r["calibration"]))
            if not h or not h.get("val_miou"):
                continue
            vax.plot(h["val_mece"], h["val_miou"], "-o", ms=2.5, lw=1, color=cmap(i % 10), label=r["calibration"])
            b = int(h.get("best_check", 0))
            vax.plot(h["val_mece"][b], h["val_miou"][b], "o", ms=10, mfc="none", mec=cmap(i % 10), mew=1.5)
            vax.plot(h["val_mece"][0], h["val_miou"][0], "s", ms=6, color=cmap(i % 10))
        vax.set_xlabel("mECE (validation voxels)")
        vax.set_ylabel("mIoU (validation voxels)")
        vax.set_title("training checkpoints (square = initial, circle = kept)", fontsize=9)
        vax.grid(alpha=0.3)
        if vax.lines:
            vax.legend(fontsize=7)
    fig.tight_layout()
    return _save(fig, path)


def plot_error_vs_confidence(tables: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, float]], path,
                             title: str = "") -> Path:
    """Per strategy, the top-label confidence histogram of correct (blue) and wrong (red)
    voxels, each normalised to its own total; the title gives the mean confidence of the
    wrong voxels and the share of them in the top bin. ``tables``: {name: (edges (B + 1,),
    correct (B,) counts, wrong (B,) counts, mean confidence of the wrong voxels)}."""
    if not tables:
        raise ValueError("plot_error_vs_confidence needs at least one table")
    n = len(tables)
    ncols = min(n, 4)
    nrows = math.ceil(n / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(3.4 * ncols, 2.8 * nrows), squeeze=False, sharey=True)
    for ax, (name, (edges, correct, wrong, mean_wrong)) in zip(axes.flat, tables.items()):
        centers, width = 0.5 * (edges[:-1] + edges[1:]), np.diff(edges)
        c_frac = correct / max(correct.sum(), 1)
        w_frac = wrong / max(wrong.sum(), 1)
        ax.bar(centers - width / 4, c_frac, width=width / 2, color="tab:blue", label="correct")
        ax.bar(centers + width / 4, w_frac, width=width / 2, color="tab:red", label="wrong")
        high = float(wrong[-1] / max(wrong.sum(), 1))
        ax.set_title(f"{name}\nwrong: mean conf {mean_wrong:.2f}, {100 * high:.0f}% >= {edges[-2]:.1f}", fontsize=8)
        ax.set_xlim(0, 1)
        ax.set_xlabel("confidence", fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in axes.flat[n:]:
        ax.axis("off")
    axes[0, 0].set_ylabel("fraction of voxels", fontsize=8)
    axes[0, 0].legend(fontsize=7)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return _save(fig, path)
