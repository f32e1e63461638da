"""The fusion bench section (eval.bench.fusion) on small ray-cast box-room frames."""
import numpy as np
import pytest

from calnav.envs.primitives import box_room_scene
from calnav.eval.bench.fusion import BenchFrames, measure
from calnav.eval.config import ConfigError, load_config
from calnav.mapping.config import MappingConfig
from calnav.mapping.registry import FUSIONS
from calnav.mapping.ground_truth import LabelledMesh
from tests.mapping.test_voxel_map import VIEWS, intrinsics, look_at


def _frames(mesh, w, h, n=3):
    k = intrinsics(w, h)
    rng = np.random.default_rng(0)
    out = []
    for eye, target in VIEWS[:n]:
        pose = look_at(eye, target)
        depth, labels = mesh.render(k, pose, w, h, depth_max_m=5.0)
        out.append((depth, rng.integers(0, 256, (h, w, 3), dtype=np.uint8), labels, pose))
    return BenchFrames(k, out)


def test_measure_reports_every_figure():
    scene = box_room_scene()
    mesh = LabelledMesh(scene.vertices, scene.triangles, scene.tri_class)
    figures = measure({(96, 72): _frames(mesh, 96, 72), (48, 36): _frames(mesh, 48, 36)}, scene.num_classes,
                      MappingConfig(block_count=1500))
    assert all(np.isfinite(v) and v > 0 for v in figures.values())
    for s in FUSIONS:
        for key in (f"fusion.{s}.ms_96x72", f"fusion.{s}.fps_48x36", f"fusion.{s}.ratio_vs_tsdf"):
            assert key in figures
    for key in ("fusion.tsdf_only_ms_96x72", "fusion.glfs_vs_rbu", "fusion.mb_per_m2", "fusion.mb_allocated"):
        assert key in figures


def test_mapping_config_through_the_config_system():
    cfg = load_config(None, ["mapping.fusion=glfs", "mapping.weighting=incidence", "mapping.temperature=2.5"])
    assert (cfg.mapping.fusion, cfg.mapping.weighting, cfg.mapping.temperature) == ("glfs", "incidence", 2.5)
    with pytest.raises(ConfigError, match="rbu"):
        load_config(None, ["mapping.fusion=bayes"])
    with pytest.raises(ConfigError, match="block_resolution"):
        load_config(None, ["mapping.block_resolution=6"])
