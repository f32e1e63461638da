"""The map-calibration results tables of the docs, rendered from committed ``calnav
calibrate-map`` records, never typed.

A page holds blocks ``<!-- calnav calibrate-map DIR -->`` ... ``<!-- /calnav calibrate-map -->``,
DIR (relative to the working directory) one segmenter's records: ``DIR/clean/results.csv`` and
``DIR/scanned/results.csv``, the study on clean houses and on their scans. ``calnav
calibrate-map --page FILE`` rewrites every block's table from them (no study runs): one row per
(fusion, calibration) of every row the clean study holds, in its order, with the scanned study's
figures beside it ("-" where it lacks the row). A test checks the committed pages against the
committed records.
"""
from __future__ import annotations

import csv
import math
import re
from pathlib import Path

from calnav.eval.config import ConfigError

BEGIN = re.compile(r"^<!-- calnav calibrate-map (\S+) -->$", re.M)
END = "<!-- /calnav calibrate-map -->"
# (study, results.csv column, header): what the docs compare, clean beside scanned
COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("clean", "miou", "clean mIoU"), ("clean", "ece", "clean ECE"), ("clean", "mece", "clean mECE"),
    ("clean", "pixel_mece", "clean pixel mECE"), ("scanned", "miou", "scanned mIoU"),
    ("scanned", "ece", "scanned ECE"), ("scanned", "mece", "scanned mECE"))
DECIMALS = 3


def read_results(path: Path) -> dict[tuple[str, str], dict]:
    """{(strategy, calibration): row} of a ``results.csv``, in its order; ConfigError naming the
    file when it is missing or lacks a column the table shows."""
    if not path.is_file():
        raise ConfigError(f"{path}: no such file; a calibrate-map block names a directory holding "
                          "clean/results.csv and scanned/results.csv")
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    needed = {"strategy", "calibration", *(c for _, c, _ in COLUMNS)}
    missing = sorted(needed - set(rows[0] if rows else ()))
    if missing:
        raise ConfigError(f"{path}: not a calibrate-map results.csv (no column {', '.join(missing)})")
    return {(r["strategy"], r["calibration"]): r for r in rows}


def _cell(row: dict | None, column: str) -> str:
    if row is None:
        return "-"
    value = float(row[column])
    return "-" if math.isnan(value) else f"{value:.{DECIMALS}f}"


def table(root: Path) -> str:
    """The Markdown table of one segmenter's records under ``root`` (module docstring)."""
    studies = {style: read_results(root / style / "results.csv") for style in ("clean", "scanned")}
    lines = ["| fusion | calibration | " + " | ".join(h for _, _, h in COLUMNS) + " |",
             "|---|---|" + "---:|" * len(COLUMNS)]
    for key in studies["clean"]:
        cells = [_cell(studies[style].get(key), column) for style, column, _ in COLUMNS]
        lines.append(f"| {key[0]} | {key[1]} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def render_page(text: str, base: Path, page: str = "page") -> str:
    """``text`` with every calibrate-map block's table rendered from the records it names
    (relative to ``base``); ConfigError for a page without a block or a block without its end."""
    out, pos, found = [], 0, 0
    for match in BEGIN.finditer(text):
        end = text.find(END, match.end())
        if end < 0:
            raise ConfigError(f"{page}: the block '{match.group(0)}' has no '{END}' line after it")
        out += [text[pos:match.end()], "\n", table(base / match.group(1)), "\n"]
        pos, found = end, found + 1
    if not found:
        raise ConfigError(f"{page}: no '<!-- calnav calibrate-map DIR -->' block to render")
    return "".join(out) + text[pos:]


def render_pages(pages: list[str], base: Path) -> None:
    """Render every page (all checked before any is written)."""
    from calnav.common.atomic import write_text_atomic

    rendered = {}
    for name in pages:
        path = Path(name)
        if not path.is_file():
            raise ConfigError(f"--page {path}: no such file")
        rendered[path] = render_page(path.read_text(encoding="utf-8"), base, str(path))
    for path, text in rendered.items():
        write_text_atomic(path, text)
        print(f"rendered {path}")
