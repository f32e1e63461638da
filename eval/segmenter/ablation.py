"""The Markdown table of a segmenter ablation folder (``agent/weights/ablation/``, made by its
``run.sh``): ``<row>_<set>.json`` eval-segmenter records and ``<row>.card.json`` training cards.

    python -m calnav.eval.segmenter.ablation agent/weights/ablation
    python -m calnav.eval.segmenter.ablation --heldout agent/weights   # the weights card's held-out tables

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

ROWS = ("shipped", "baseline", "photometric", "jpeg", "recolour", "recolour25", "recolour10", "all", "ft", "ft_recolour10",
        "ft_recolour25", "ft_fresh")
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


HELDOUT_MODELS = ("learned_rgb", "learned_rgbd", "noisy", "gt")   # rows of the held-out table, in this order
HELDOUT_COLUMNS = (("accuracy", "accuracy"), ("mIoU all", "miou"), ("mIoU goal+structure", "miou_goal_structure"),
                   ("ECE", "ece"), ("TL-ECE", "tl_ece"), ("mECE", "mece"), ("Brier", "brier"),
                   ("mean confidence", "mean_confidence"))


def heldout_tables(folder: Path | str, frames: int = 2000) -> str:
    """The weights card's held-out tables from the eval records ``<model>[.scanned].eval<frames>.json``
    in ``folder`` (``agent/weights``): one line per record (``HELDOUT_MODELS`` order, clean before
    scanned) with ``HELDOUT_COLUMNS``, then per-class IoU with one column per learned model's
    record. ValueError when the folder holds no such record."""
    folder = Path(folder)
    found = [(m, style, json.loads(p.read_text())) for m in HELDOUT_MODELS for style in ("clean", "scanned")
             if (p := folder / f"{m}{'.scanned' if style == 'scanned' else ''}.eval{frames}.json").exists()]
    if not found:
        raise ValueError(f"{folder} holds no <model>[.scanned].eval{frames}.json records")
    lines = ["| model | frames | " + " | ".join(label for label, _ in HELDOUT_COLUMNS) + " |",
             "|---|---|" + "---:|" * len(HELDOUT_COLUMNS)]
    lines += [f"| {m} | {style} | " + " | ".join(f"{r[key]:.3f}" for _, key in HELDOUT_COLUMNS) + " |"
              for m, style, r in found]
    learned = [(m, style, r) for m, style, r in found if m.startswith("learned")]
    classes = list(learned[0][2]["per_class_iou"]) if learned else []
    per_class = ["| class | " + " | ".join(f"{m} {style}" for m, style, _ in learned) + " |",
                 "|---|" + "---:|" * len(learned)]
    per_class += [f"| {c} | " + " | ".join("-" if r["per_class_iou"].get(c) is None else f"{r['per_class_iou'][c]:.3f}"
                                          for _, _, r in learned) + " |" for c in classes]
    return "\n".join(lines) + ("\n\n" + "\n".join(per_class) if learned else "")


if __name__ == "__main__":   # python -m calnav.eval.segmenter.ablation FOLDER | --heldout [agent/weights]
    if sys.argv[1:2] == ["--heldout"]:
        print(heldout_tables(sys.argv[2] if len(sys.argv) > 2 else "agent/weights"))
    else:
        print(ablation_table(sys.argv[1] if len(sys.argv) > 1 else "agent/weights/ablation"))
