"""The Markdown table of a segmenter ablation folder (``agent/weights/ablation/``, made by its
``run.sh``): ``<row>_<set>.json`` eval-segmenter records and ``<row>.card.json`` training cards.

    python -m calnav.eval.segmenter.ablation agent/weights/ablation

One line per (row, evaluation set), rows in the order of ``ROWS`` then any others by name, sets
in the order of ``SETS``: mIoU over all classes present, mIoU over goal + structure classes,
ECE, and the row's training wall time (its card's ``train_wall_s``). When the folder's records
carry per-house confusions (``scene_confusion``), one more column: each row's goal + structure
mIoU minus the reference row's (``shipped``, else ``baseline``) on the same frames, with its
paired house-level standard error (``paired_miou_difference``).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

ROWS = ("shipped", "baseline", "photometric", "jpeg", "recolour", "recolour25", "recolour10", "all")
REFERENCE_ROWS = ("shipped", "baseline")   # the row the others are paired with, the first present
SETS = ("clean", "scanned", "camera", "recoloured")
SET_LABELS = {"clean": "clean", "scanned": "scanned", "camera": "scanned + camera shift",
              "recoloured": "scanned, houses recoloured"}


def _miou(confusion, ids: list[int]) -> float:
    from calnav.mapping.metrics import iou_of_confusion

    iou = iou_of_confusion(confusion)[ids]
    return float(np.nanmean(iou)) if np.isfinite(iou).any() else float("nan")


def paired_miou_difference(a: dict, b: dict, classes: tuple[str, ...] | None = None) -> tuple[float, float, int]:
    """mIoU of eval record ``b`` minus record ``a`` (over ``classes`` present; default: the
    classes of ``a``'s ``miou_goal_structure``), the two scored on the same frames, with the
    house-level jackknife standard error of the difference (``eval.stats.jackknife_sem``: each
    house left out of both records at once, so the houses' shared difficulty cancels) and the
    number of houses. ValueError when a record has no ``scene_confusion`` or the frames differ."""
    from calnav.eval.stats import jackknife_sem

    for name, r in (("a", a), ("b", b)):
        if "scene_confusion" not in r:
            raise ValueError(f"record {name} has no scene_confusion (scored before per-house counts were recorded)")
    if a.get("frames_sha256") != b.get("frames_sha256"):
        raise ValueError("the two records scored different frames (frames_sha256 differs): no paired difference")
    names = list(a["per_class_iou"])
    ids = [names.index(c) for c in (classes or a["classes_in_miou_goal_structure"])]
    ca, cb = np.asarray(a["scene_confusion"], np.int64), np.asarray(b["scene_confusion"], np.int64)
    if ca.shape != cb.shape:
        raise ValueError(f"scene_confusion shapes differ: {ca.shape} and {cb.shape}")
    ta, tb = ca.sum(axis=0), cb.sum(axis=0)
    diff = _miou(tb, ids) - _miou(ta, ids)
    loo = [_miou(tb - cb[g], ids) - _miou(ta - ca[g], ids) for g in range(len(ca))]
    return diff, jackknife_sem(loo), len(ca)


def ablation_table(folder: Path | str) -> str:
    """The folder's records as a Markdown table (module docstring); ValueError when it has none."""
    folder = Path(folder)
    records: dict[tuple[str, str], dict] = {}
    for path in folder.glob("*.json"):
        stem = path.stem
        if stem.endswith(".card"):
            continue
        row, _, ev = stem.rpartition("_")
        if ev in SETS and row:
            records[row, ev] = json.loads(path.read_text())
    if not records:
        raise ValueError(f"{folder} holds no <row>_<set>.json eval records (sets: {', '.join(SETS)})")
    names = sorted({r for r, _ in records}, key=lambda r: (ROWS.index(r) if r in ROWS else len(ROWS), r))
    reference = next((r for r in REFERENCE_ROWS if r in names), None)
    paired = reference is not None and any("scene_confusion" in m for m in records.values())
    lines = ["| training | frames | mIoU all | mIoU goal+structure | ECE | training wall time |"
             + (f" goal+structure - {reference} (SE) |" if paired else ""),
             "|---|---|---:|---:|---:|---:|" + ("---:|" if paired else "")]
    for row in names:
        card = folder / f"{row}.card.json"
        wall = f"{json.loads(card.read_text())['train_wall_s'] / 60:.1f} min" if card.exists() else "-"
        for ev in SETS:
            m = records.get((row, ev))
            if m is not None:
                line = (f"| {row} | {SET_LABELS[ev]} | {m['miou']:.3f} | {m['miou_goal_structure']:.3f} "
                        f"| {m['ece']:.3f} | {wall} |")
                if paired:
                    line += f" {_difference_cell(records.get((reference, ev)), m, row == reference)} |"
                lines.append(line)
    return "\n".join(lines)


def _difference_cell(ref: dict | None, m: dict, is_reference: bool) -> str:
    """``+0.012 (0.008)``, or ``-`` for the reference row itself or where no pairing exists."""
    if is_reference or ref is None or "scene_confusion" not in ref or "scene_confusion" not in m \
            or ref.get("frames_sha256") != m.get("frames_sha256"):
        return "-"
    diff, se, _ = paired_miou_difference(ref, m)
    return f"{diff:+.3f} ({se:.3f})"


if __name__ == "__main__":
    print(ablation_table(sys.argv[1] if len(sys.argv) > 1 else "agent/weights/ablation"))
