"""The mECE-vs-temperature curve of the fixed fusion strategies (is the 3D temperature search
trapped in a local minimum?).

``mapping.calibration.fit.fit_temperature_3d`` searches a 21-point log grid over [0.01, 200]
and refines around the best grid point; a second, deeper minimum between grid points or beyond
200 would be missed. The authors' Bayesian optimisation found T = 80-131 for RBU, an order of
magnitude above calnav's 6.2 / 3.8. This evaluates the fused calibration-train map's mECE on a
dense log grid over ``TAU_CURVE_RANGE`` = [0.01, 300] for every fixed strategy (the same voxels
the search scores), so the whole objective is visible: ``tau_curve.csv`` and ``tau_curve.png``.
"""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from calnav.common.atomic import atomic_path
from calnav.eval.sections import TAU_CURVE_RANGE
from calnav.mapping.calibration.fit import MapObjective
from calnav.mapping.calibration.flat_obs import FlatObservations

CSV_COLUMNS = ("segmenter", "strategy", "temperature", "mece", "miou")


def temperature_curve(flat: FlatObservations, strategies: list[str], points: int,
                      tau_range: tuple[float, float] = TAU_CURVE_RANGE, progress: bool = True) -> dict:
    """{"temperature": [points] log-spaced, strategy: {"mece": [points], "miou": [points]}} of the
    maps fused from ``flat`` at each temperature (mIoU too: a temperature can move argmaxes)."""
    from tqdm import tqdm

    from calnav.mapping import metrics

    taus = np.exp(np.linspace(math.log(tau_range[0]), math.log(tau_range[1]), points))
    labels = flat.labels.numpy()
    out: dict = {"temperature": taus.tolist()}
    bar = tqdm(total=len(strategies) * points, desc="mECE vs temperature", unit="map", disable=not progress)
    for s in strategies:
        f = MapObjective(flat, s)
        mece, miou = [], []
        for t in taus:
            st = metrics.CalibrationStats(flat.num_classes).update(f.probs(np.float32(t)), labels)
            mece.append(st.mece())
            miou.append(st.miou())
            bar.update()
        out[s] = {"mece": mece, "miou": miou}
    bar.close()
    return out


def curve_minima(temperature: list[float], mece: list[float]) -> list[int]:
    """Indices of the local minima of a sampled curve (strictly lower than the neighbours on
    both sides, plateaus counted once; the ends count against their one neighbour)."""
    y = np.asarray(mece, dtype=np.float64)
    n = len(y)
    out = []
    i = 0
    while i < n:
        j = i
        while j + 1 < n and y[j + 1] == y[i]:
            j += 1                      # plateau [i, j]
        left = i == 0 or y[i - 1] > y[i]
        right = j == n - 1 or y[j + 1] > y[i]
        if left and right and n > 1:
            out.append(i)
        i = j + 1
    return out


def write_tau_curves(out: Path, curves: dict[str, dict], fitted: dict[str, dict[str, float]]) -> list[Path]:
    """``tau_curve.csv`` (one row per segmenter, strategy and temperature) and ``tau_curve.png``
    (mECE against temperature, log x, one panel per segmenter, the fitted 3D temperature
    marked). ``curves``: {segmenter: temperature_curve()}; ``fitted``: {segmenter: {strategy: tau}}."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not curves:
        return []
    with atomic_path(out / "tau_curve.csv") as tmp, open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(CSV_COLUMNS)
        for seg, c in curves.items():
            for s, v in c.items():
                if s == "temperature":
                    continue
                for t, m, iou in zip(c["temperature"], v["mece"], v["miou"]):
                    w.writerow([seg, s, f"{t:.6g}", f"{m:.6f}", f"{iou:.6f}"])
    fig, axes = plt.subplots(1, len(curves), figsize=(5.2 * len(curves), 3.8), squeeze=False)
    for ax, (seg, c) in zip(axes[0], curves.items()):
        for s, v in c.items():
            if s == "temperature":
                continue
            line, = ax.plot(c["temperature"], v["mece"], "-", lw=1.4, label=s)
            tau = fitted.get(seg, {}).get(s)
            if tau is not None and np.ndim(tau) == 0:
                ax.axvline(float(tau), color=line.get_color(), ls=":", lw=1)
            for i in curve_minima(c["temperature"], v["mece"]):
                ax.plot(c["temperature"][i], v["mece"][i], "o", color=line.get_color(), ms=4)
        ax.set_xscale("log")
        ax.set_xlabel("3D temperature (log scale)")
        ax.set_ylabel("mECE of the fused calibration-train map")
        ax.set_title(f"{seg}: dots = local minima, dotted = fitted tau", fontsize=9)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "tau_curve.png", dpi=100)
    plt.close(fig)
    return [out / "tau_curve.csv", out / "tau_curve.png"]
