"""The ``hm3d`` bench section's HM3D-size scene is the bench house's surfaces, finer."""
import numpy as np

from calnav.eval.bench.context import BenchContext
from calnav.eval.bench.hm3d import run, subdivide


def _areas(scene) -> np.ndarray:
    t = scene.vertices[scene.triangles].astype(np.float64)
    return np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1) / 2


def test_subdivision_keeps_every_surface_its_labels_and_its_area():
    ctx = BenchContext(quick=True)
    house = ctx.scene
    fine = subdivide(house, 2)
    assert len(fine.triangles) == 16 * len(house.triangles)
    for k in np.unique(house.tri_class):   # each class covers the same area, split 16 ways
        assert np.isclose(_areas(fine)[fine.tri_class == k].sum(), _areas(house)[house.tri_class == k].sum(), rtol=1e-5)
    assert set(np.unique(fine.tri_instance)) == set(np.unique(house.tri_instance))
    used = house.vertices[house.triangles].reshape(-1, 3)
    np.testing.assert_allclose(fine.vertices.min(0), used.min(0), atol=1e-6)


def test_the_quick_section_measures_a_scene_read_back_from_hm3d_files():
    out = run(BenchContext(quick=True, n_poses=12))
    assert out["hm3d.scene_triangles"] == 16 * len(BenchContext().scene.triangles)
    assert all(np.isfinite(v) and v > 0 for v in out.values())
