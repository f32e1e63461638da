"""Bench figures in the docs, rendered from a committed ``calnav bench`` output.

A page quotes figures in tables headed ``| figure | meaning | measured | target |``; each row's
first cell names a figure (```fusion.glfs_vs_rbu```). ``render_page`` writes every such row's
"measured" cell from a bench output (the flat JSON ``calnav bench --output`` writes), so the
numbers on the page are the run's, never typed: ``calnav bench --from JSON --page FILE``
re-renders a page, ``calnav bench --output JSON --page FILE`` measures and renders, and a test
checks the committed pages against the committed outputs. The meaning and target cells are the
page's own words.

``write_manifest`` writes ``<output>.manifest.json`` beside an output: the command, the source
commit, the date, the machine and the library versions the figures were measured with.
"""
from __future__ import annotations

import json
import math
import os
import platform
import shlex
import sys
from datetime import datetime, timezone
from pathlib import Path

from calnav.eval.config import ConfigError

HEADER = "| figure | meaning | measured | target |"
MEASURED_COLUMN = 2      # the cell a figure's value goes in (0-based)


def format_figure(value: float | None) -> str:
    """A figure as the docs print it: 3 significant digits (2.00, 0.912, 41.2), whole numbers
    from 100 on (thousands separated); a figure the run could not measure (JSON null) as '-'."""
    if value is None or not math.isfinite(value):
        return "-"
    if abs(value) >= 100:
        return f"{value:,.0f}"
    return f"{value:#.3g}"


def render_page(text: str, figures: dict[str, float | None], page: str = "page") -> str:
    """``text`` with the measured cell of every figure row (in tables under ``HEADER``) set from
    ``figures``; a row naming a figure the output lacks, or a page without such a table, is a
    one-line ConfigError naming it."""
    lines, out, in_table, seen = text.split("\n"), [], False, 0
    for line in lines:
        if line.strip() == HEADER:
            in_table = True
        elif in_table and not line.startswith("|"):
            in_table = False
        elif in_table and not line.startswith("|---"):
            cells = [c.strip() for c in line.strip().removeprefix("|").removesuffix("|").split("|")]
            name = cells[0].strip("`")
            if name not in figures:
                raise ConfigError(f"{page}: figure {name!r} is not in the bench output; its figures: "
                                  f"{', '.join(sorted(figures)[:8])}, ...")
            cells[MEASURED_COLUMN] = format_figure(figures[name])
            line, seen = "| " + " | ".join(cells) + " |", seen + 1
        out.append(line)
    if not seen:
        raise ConfigError(f"{page}: no table headed '{HEADER}' to render")
    return "\n".join(out)


def read_output(path: Path) -> dict[str, float | None]:
    """A ``calnav bench`` output; a missing or unreadable one is a one-line ConfigError."""
    try:
        figures = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"--from {path}: no such file; give the JSON `calnav bench --output` wrote") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"--from {path}: not JSON ({exc})") from None
    if not isinstance(figures, dict) or not all(isinstance(v, (int, float, type(None))) for v in figures.values()):
        raise ConfigError(f"--from {path}: not a bench output (a flat JSON of figure -> number)")
    return figures


def render_pages(pages: list[str], figures: dict[str, float | None]) -> dict[Path, str]:
    """{page: its rendered text} for every page, all checked before any is written."""
    out = {}
    for name in pages:
        path = Path(name)
        if not path.is_file():
            raise ConfigError(f"--page {path}: no such file")
        out[path] = render_page(path.read_text(encoding="utf-8"), figures, str(path))
    return out


def manifest_path(output: str | Path) -> Path:
    output = Path(output)
    return output.with_name(output.stem + ".manifest.json")


def write_manifest(output: str | Path, argv: list[str]) -> Path:
    """``<output>.manifest.json``: how the figures in ``output`` were measured."""
    from calnav.common.atomic import write_json_atomic
    from calnav.common.provenance import cpu_model, git_commit

    versions = {"python": platform.python_version()}
    for module in ("numpy", "torch", "open3d"):
        if module in sys.modules:
            versions[module] = getattr(sys.modules[module], "__version__", "?")
    path = manifest_path(output)
    write_json_atomic(path, {
        "command": shlex.join(["calnav", *argv]), "output": Path(output).name, "commit": git_commit(),
        "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "machine": {"cpus": os.cpu_count(), "cpu": cpu_model(), "system": platform.platform()},
        "versions": versions})
    return path

