"""Bench figures on doc pages are rendered from a bench output (``eval.bench.page``), and the
committed pages are the committed output's rendering."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from calnav.eval.bench.page import HEADER, format_figure, manifest_path, render_page
from calnav.eval.cli import main
from calnav.eval.config import ConfigError

REPO = Path(__file__).resolve().parents[3]
OUTPUT = REPO / "docs" / "measured" / "bench.json"
PAGES = ("docs/measured.md", "docs/scanned_houses.md", "docs/rerun.md")
GPU_OUTPUT, GPU_PAGES = REPO / "docs" / "measured" / "h200" / "bench.json", ("docs/segmenters.md",)

PAGE = f"""# speed

{HEADER}
|---|---|---|---|
| `a.ms` | one thing, ms | 99 (typed) | <= 10 |
| `b.ratio` | a ratio | | <= 1.2 |

text after, | not a row
"""


def test_format():
    assert [format_figure(v) for v in (12.345, 0.91234, 2.0, 5.0, 1984.2, 487.0, None, float("nan"))] == \
        ["12.3", "0.912", "2.00", "5.00", "1,984", "487", "-", "-"]


def test_rows_get_the_outputs_figures_and_nothing_else_changes():
    out = render_page(PAGE, {"a.ms": 12.345, "b.ratio": 1.07, "c": 3.0})
    assert "| `a.ms` | one thing, ms | 12.3 | <= 10 |" in out and "| `b.ratio` | a ratio | 1.07 | <= 1.2 |" in out
    assert out.replace("12.3", "99 (typed)").replace("| 1.07 |", "| |") == PAGE
    with pytest.raises(ConfigError, match=r"^p.md: figure 'b.ratio' is not in the bench output"):
        render_page(PAGE, {"a.ms": 1.0}, "p.md")
    with pytest.raises(ConfigError, match="no table headed"):
        render_page("# nothing\n", {"a.ms": 1.0})


def test_cli_renders_from_an_output_and_checks_every_page_first(tmp_path, capsys):
    output, page, bad = tmp_path / "bench.json", tmp_path / "page.md", tmp_path / "bad.md"
    output.write_text(json.dumps({"a.ms": 12.345, "b.ratio": None}))
    page.write_text(PAGE)
    bad.write_text(PAGE.replace("`b.ratio`", "`zz`"))
    assert main(["bench", "--from", str(output), "--page", str(page), "--page", str(bad)]) == 2
    assert "figure 'zz' is not in the bench output" in capsys.readouterr().err and page.read_text() == PAGE
    assert main(["bench", "--from", str(output), "--page", str(page)]) == 0
    assert "| `b.ratio` | a ratio | - | <= 1.2 |" in page.read_text()
    assert main(["bench", "--from", str(tmp_path / "none.json"), "--page", str(page)]) == 2
    assert "no such file" in capsys.readouterr().err


def test_the_committed_pages_are_the_committed_runs_rendering():
    """docs/measured.md and the scanned-houses speed table are `calnav bench --from
    docs/measured/bench.json --page ...`'s rendering; the output has its manifest."""
    figures = json.loads(OUTPUT.read_text())
    manifest = json.loads(manifest_path(OUTPUT).read_text())
    assert manifest["command"].startswith("calnav bench --output docs/measured/bench.json") and manifest["commit"]
    for page in PAGES:
        text = (REPO / page).read_text(encoding="utf-8")
        assert render_page(text, figures, page) == text, f"{page}: rerun calnav bench --from ... --page {page}"


def test_the_gpu_figures_are_the_gpu_runs_rendering():
    """docs/segmenters.md's CUDA table is `calnav bench --from docs/measured/h200/bench.json
    --page docs/segmenters.md`'s rendering; the script that made the output is beside it."""
    figures = json.loads(GPU_OUTPUT.read_text())
    assert (GPU_OUTPUT.parent / "run.sh").is_file()
    assert any(k.endswith("cuda_ms_640x480") for k in figures)
    for page in GPU_PAGES:
        text = (REPO / page).read_text(encoding="utf-8")
        assert render_page(text, figures, page) == text, f"{page}: rerun calnav bench --from ... --page {page}"


def test_the_hm3d_figures_are_the_hm3d_runs_rendering():
    """docs/datasets.md's size table is `calnav bench --from docs/datasets/bench_hm3d.json
    --page docs/datasets.md`'s rendering of the run its manifest names."""
    output = REPO / "docs" / "datasets" / "bench_hm3d.json"
    figures = json.loads(output.read_text())
    assert json.loads(manifest_path(output).read_text())["command"].startswith("calnav bench --only hm3d")
    assert figures["hm3d.scene_triangles"] >= 1e6   # HM3D's size, not the house's
    text = (REPO / "docs" / "datasets.md").read_text(encoding="utf-8")
    assert render_page(text, figures, "docs/datasets.md") == text
