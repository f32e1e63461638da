"""The Markdown table of a segmenter ablation folder (``agent/weights/ablation/``, made by its
``run.sh``): ``<row>_<set>.json`` eval-segmenter records and ``<row>.card.json`` training cards.

    python -m calnav.eval.segmenter.ablation agent/weights/ablation

One line per (row, evaluation set), rows in the order of ``ROWS`` then any others by name, sets
in the order of ``SETS``: mIoU over all classes present, mIoU over goal + structure classes,
ECE, and the row's training wall time (its card's ``train_wall_s``).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

ROWS = ("baseline", "photometric", "jpeg", "recolour", "recolour25", "all")
SETS = ("clean", "scanned", "camera", "recoloured")
SET_LABELS = {"clean": "clean", "scanned": "scanned", "camera": "scanned + camera shift",
              "recoloured": "scanned, houses recoloured"}


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
    lines = ["| training | frames | mIoU all | mIoU goal+structure | ECE | training wall time |",
             "|---|---|---:|---:|---:|---:|"]
    for row in names:
        card = folder / f"{row}.card.json"
        wall = f"{json.loads(card.read_text())['train_wall_s'] / 60:.1f} min" if card.exists() else "-"
        for ev in SETS:
            m = records.get((row, ev))
            if m is not None:
                lines.append(f"| {row} | {SET_LABELS[ev]} | {m['miou']:.3f} | {m['miou_goal_structure']:.3f} "
                             f"| {m['ece']:.3f} | {wall} |")
    return "\n".join(lines)


if __name__ == "__main__":
    print(ablation_table(sys.argv[1] if len(sys.argv) > 1 else "agent/weights/ablation"))
