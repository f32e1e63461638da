"""docs/calibration.md's results tables are `calnav calibrate-map --page`'s rendering of the
committed records (eval.calibration.page), and the renderer's rules by hand."""
from pathlib import Path

import pytest

from calnav.eval.calibration.page import render_page, table
from calnav.eval.config import ConfigError

REPO = Path(__file__).resolve().parents[3]
HEADER = "segmenter,strategy,calibration,miou,miou_authors,ece,tl_ece,mece,brier,pixel_mece,n_voxels\n"


def _study(root: Path, style: str, rows: list[str]) -> None:
    (root / style).mkdir(parents=True)
    (root / style / "results.csv").write_text(HEADER + "".join(r + "\n" for r in rows))


def test_the_committed_page_is_the_committed_records_rendering():
    text = (REPO / "docs" / "calibration.md").read_text(encoding="utf-8")
    assert render_page(text, REPO, "docs/calibration.md") == text, \
        "rerun calnav calibrate-map --page docs/calibration.md"
    assert text.count("<!-- calnav calibrate-map docs/calibrate_map/") == 2
    assert "| rbu | vector_3d |" in text   # every row of the records, not a chosen few


def test_rows_follow_the_clean_study_and_scanned_rows_it_lacks_are_dashes(tmp_path):
    _study(tmp_path, "clean", ["s,rbu,none,0.56691,0.5,0.04049,0.1,0.24136,0.1,0.10744,9",
                               "s,glfs,learned,0.5,0.5,0.01,0.1,0.07,0.1,0.08,9"])
    _study(tmp_path, "scanned", ["s,rbu,none,0.5186,0.5,0.05,0.1,nan,0.1,0.1,9"])
    assert table(tmp_path).splitlines()[2:] == [
        "| rbu | none | 0.567 | 0.040 | 0.241 | 0.107 | 0.519 | 0.050 | - |",   # NaN: '-'
        "| glfs | learned | 0.500 | 0.010 | 0.070 | 0.080 | - | - | - |"]         # not in the scanned study


def test_page_errors_name_the_problem(tmp_path):
    with pytest.raises(ConfigError, match="no '<!-- calnav calibrate-map DIR -->' block"):
        render_page("# nothing\n", tmp_path, "p.md")
    with pytest.raises(ConfigError, match="has no '<!-- /calnav calibrate-map -->' line after it"):
        render_page("<!-- calnav calibrate-map x -->\n", tmp_path, "p.md")
    with pytest.raises(ConfigError, match=r"x/clean/results.csv: no such file"):
        render_page("<!-- calnav calibrate-map x -->\n<!-- /calnav calibrate-map -->\n", tmp_path, "p.md")
