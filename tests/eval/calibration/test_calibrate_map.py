"""`calnav calibrate-map` / `calnav fit-glfs` end to end on a tiny study (the e2e marker: `make
test` runs it with 1 + 1 + 1 houses and short scans)."""
from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from tests.conftest import small_or_full
from calnav.eval.cli import main

pytestmark = pytest.mark.e2e

FRAMES = small_or_full(40, 300)
# the houses recorded in this process (small: the process pool's start-up, two interpreters
# importing torch, cost more than the three houses; tests/eval/test_backends.py records them on
# the pool); full size on the pool, as a user runs the study
WORKERS = small_or_full("run.workers=1", "run.workers=0")
TINY = [WORKERS, 
    "study.segmenters=[learned_rgb]", "study.strategies=[rbu,histogram,glfs]",
    "study.calib_train_scenes=1", "study.calib_val_scenes=1", "study.test_scenes=1", f"scan.frames={FRAMES}",
    "study.fit_max_voxels=3000", "study.grid_points=7", "study.refine_iters=3", "study.vector_sweeps=1",
    "study.vector_refine_iters=2", "study.glfs_max_voxels=5000", "glfs.epochs=2", "study.tau_curve_points=5",
    "study.figure_views=1", "study.figure_resolution=64x48",
    "study.glfs_variants=[{name: learned, overrides: {}}, {name: authors, overrides: {learn_gates: false, "
    "init_tau: 0.4, selection: val_miou, val_per_epoch: 2}}]",
]


def test_calibrate_map_writes_results_resumes_and_refuses_another_config(tmp_path, capsys):
    out = tmp_path / "study"
    assert main(["calibrate-map", "--output", str(out), *TINY]) == 0
    printed = capsys.readouterr().out
    assert "temperature_3d" in printed and "learned" in printed
    with open(out / "results.csv") as f:
        reader = csv.DictReader(f)
        assert reader.fieldnames == ["segmenter", "strategy", "calibration", "miou", "miou_authors", "ece", "tl_ece",
                                     "mece", "brier", "pixel_mece", "n_voxels"]
        rows = list(reader)
    assert [(r["strategy"], r["calibration"]) for r in rows] == [
        ("rbu", "none"), ("rbu", "temperature_2d"), ("rbu", "temperature_3d"), ("rbu", "vector_3d"),
        ("histogram", "none"), ("histogram", "temperature_2d"), ("histogram", "temperature_3d"),
        ("histogram", "vector_3d"), ("glfs", "learned"), ("glfs", "authors")]
    for r in rows:
        for key in ("miou", "miou_authors", "ece", "tl_ece", "mece", "pixel_mece"):
            assert 0.0 <= float(r[key]) <= 1.0, (key, r)
        assert 0.0 <= float(r["brier"]) <= 2.0 and int(r["n_voxels"]) > 1000
    # a scalar temperature cannot move histogram votes: identical maps
    hist = {r["calibration"]: r for r in rows if r["strategy"] == "histogram"}
    assert hist["none"]["mece"] == hist["temperature_3d"]["mece"]
    # void voxels predicted as a class are extra false positives in the authors' convention
    assert all(float(r["miou_authors"]) <= float(r["miou"]) + 0.05 for r in rows)
    md = (out / "results.md").read_text()
    assert "## learned_rgb" in md and "## GLFS pick" in md
    pick = json.loads((out / "glfs_pick.json").read_text())["learned_rgb"]
    assert pick["best_fixed"].split("/")[0] in ("rbu", "histogram") and pick["pick"] in (None, "learned", "authors")
    for png in ("calibration_vs_accuracy.png", "reliability_learned_rgb.png", "reliability_classes_learned_rgb.png",
                "glfs_tradeoff.png", "error_vs_confidence_learned_rgb.png", "tau_curve.png",
                "qualitative_learned_rgb.png"):
        assert (out / png).stat().st_size > 10_000, png
    with open(out / "tau_curve.csv") as f:
        curve = list(csv.DictReader(f))
    assert len(curve) == 2 * 5 and {r["strategy"] for r in curve} == {"rbu", "histogram"}
    assert float(curve[0]["temperature"]) == pytest.approx(0.01) and float(curve[4]["temperature"]) == pytest.approx(300)
    qual = json.loads((out / "qualitative_learned_rgb.json").read_text())
    assert len(qual["views"]) == 1 and {"RBU", "GLFS"} <= set(qual["views"][0])
    assert qual["views"][0]["RBU"]["pixels"] > 0
    try:
        import rerun  # noqa: F401  (the viz extra: make test installs it)
    except ImportError:
        assert not (out / "qualitative_learned_rgb.rrd").exists()
    else:   # the same house in 3D, RBU and GLFS side by side
        from calnav.common.rerun_io import read_columns

        cols = read_columns(out / "qualitative_learned_rgb.rrd")
        for tree in ("rbu", "glfs"):
            for part in ("class", "confidence", "correct", "wrong"):
                assert f"/{tree}/world/map/{part}" in cols, (tree, part)
            n = len(cols[f"/{tree}/world/map/class"].column("Points3D:positions").to_pylist()[0])
            split = sum(len(cols[f"/{tree}/world/map/{p}"].column("Points3D:positions").to_pylist()[0])
                        for p in ("correct", "wrong"))
            assert 0 < split <= n
        assert "/world/mesh" in cols and "/world/scan" in cols
    fits = json.loads((out / "fits" / "learned_rgb" / "fits.json").read_text())
    assert {"temperature_2d", "temperature_3d/rbu", "vector_3d/rbu", "glfs/learned", "glfs/authors",
            "tau_curve"} <= set(fits)
    assert len(fits["vector_3d/rbu"]["temperature"]) == 18
    authors = fits["glfs/authors"]
    assert authors["g"] == 0.0 and authors["eps"] == 0.0 and len(authors["val_miou"]) == 1 + 2 * 2

    # resume: nothing is recomputed, the table is the same
    stamps = {p: p.stat().st_mtime_ns for p in out.rglob("*.npz")}
    assert main(["calibrate-map", "--output", str(out), *TINY]) == 0
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*.npz")} == stamps
    with open(out / "results.csv") as f:
        assert list(csv.DictReader(f)) == rows

    capsys.readouterr()
    assert main(["calibrate-map", "--output", str(out), *TINY, "study.grid_points=9"]) == 2
    assert "--force" in capsys.readouterr().err


def test_fit_glfs_writes_params_a_map_can_use(tmp_path, capsys):
    from calnav.agent.segmenters.base import default_class_names
    from calnav.mapping.config import MappingConfig
    from calnav.mapping.glfs import GLFSParams
    from calnav.mapping.voxel_map import SemanticVoxelMap

    dest = tmp_path / "glfs_rgb.json"
    # fit-glfs sets study.segmenters (its --segmenter) and study.strategies ([glfs]) itself
    tiny = [o for o in TINY if not o.startswith(("study.segmenters=", "study.strategies="))]
    assert main(["fit-glfs", "--segmenter", "learned_rgb", "--output", str(dest), "--work-dir", str(tmp_path / "w"),
                 "--variant", "authors", *tiny]) == 0
    params = GLFSParams.load(dest)
    assert params.class_names == default_class_names() and math.isfinite(params.g) and np.all(params.tau > 0)
    vmap = SemanticVoxelMap(18, MappingConfig(fusion="glfs", glfs_params=str(dest)), class_names=default_class_names())
    np.testing.assert_allclose(vmap.glfs_params.tau, params.tau)
    assert params.g == 0.0 and params.eps == 0.0          # the authors' fixed gates
    # the kept checkpoint's validation figures, from the fit's own history (not the last epoch's)
    hist = json.loads((tmp_path / "w" / "fits" / "learned_rgb" / "fits.json").read_text())["glfs/authors"]
    k = hist["best_check"]
    assert (f"kept: validation check {k} of {len(hist['val_miou']) - 1} (epoch {hist['best_epoch']:.2f}, "
            f"glfs.selection=val_miou): validation mIoU {hist['val_miou'][k]:.3f}, mECE {hist['val_mece'][k]:.3f}"
            in capsys.readouterr().out)
    assert main(["fit-glfs", "--segmenter", "learned_rgb", "--output", str(dest), "--variant", "nope", *tiny]) == 2
    assert "unknown GLFS variant 'nope'" in capsys.readouterr().err


def test_calibrate_map_bad_config(capsys):
    assert main(["calibrate-map", "study.calibrations=[none,platt]"]) == 2
    err = capsys.readouterr().err
    assert "unknown calibration 'platt'" in err and "temperature_3d" in err
    assert main(["calibrate-map", "study.glfs_variants=[{name: x, overrides: {selection: best}}]"]) == 2
    assert "unknown selection 'best'; valid: val_loss, val_miou, constrained" in capsys.readouterr().err
    assert main(["calibrate-map", "study.glfs_variants=[{name: x, overrides: {lr: 0.1, gates: 1}}]"]) == 2
    assert "unknown config key 'study.glfs_variants.x.overrides.gates'" in capsys.readouterr().err
