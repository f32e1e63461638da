"""Scanned houses carry a real scan's floor: rugs, thresholds and clutter in the house the scanner
sees, then holes beside furniture, unlabelled floor patches and a low-frequency warp."""
from __future__ import annotations

import numpy as np
import pytest

from calnav.envs.scanning.artifacts import apply_floor_artifacts, hole_centres, warp_field
from calnav.envs.scanning.config import ScanningConfig
from calnav.envs.scanning.lived_in import lived_in
from calnav.envs.semantics import CLASS_ID, VOID


@pytest.fixture(scope="module")
def house():
    from calnav.envs.scenes import load_scene

    return load_scene("house_val_0000")


def _floor_grid(x0, y0, x1, y1, step=0.1):
    """A labelled floor sheet (vertices, triangles, class, instance) of small triangles."""
    xs, ys = np.arange(x0, x1 + 1e-9, step), np.arange(y0, y1 + 1e-9, step)
    gx, gy = np.meshgrid(xs, ys)
    v = np.stack([gx, gy, np.zeros_like(gx)], -1).reshape(-1, 3)
    idx = np.arange(len(v)).reshape(gx.shape)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    t = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return v, t, np.full(len(t), CLASS_ID["floor"], np.int16), np.full(len(t), 1, np.int32)


def test_lived_in_adds_rugs_thresholds_and_unlabelled_clutter(house):
    cfg = ScanningConfig(rug_prob=1.0, threshold_prob=1.0, clutter_per_m2=0.2)
    lived = lived_in(house, cfg, np.random.default_rng(0))
    n = lived.meta["lived_in"]
    assert n["rugs"] >= 1 and n["thresholds"] == len(house.meta["doors"]) and n["clutter"] >= 5
    extra = slice(len(house.triangles), None)
    assert (lived.tri_class[extra] == VOID).all() and (lived.tri_instance[extra] == -1).all()
    z = lived.vertices[len(house.vertices):, 2]
    assert z.min() == pytest.approx(house.floor_z) and z.max() <= 0.3 + 1e-6
    np.testing.assert_array_equal(lived.vertices[:len(house.vertices)], house.vertices)   # the house itself is kept
    again = lived_in(house, cfg, np.random.default_rng(0))
    np.testing.assert_array_equal(again.vertices, lived.vertices)
    bare = lived_in(house, ScanningConfig(rug_prob=0, threshold_prob=0, clutter_per_m2=0), np.random.default_rng(0))
    assert len(bare.triangles) == len(house.triangles)


def test_holes_sit_beside_furniture(house):
    cfg = ScanningConfig(holes_per_m2=0.3, hole_near_furniture=1.0)
    centres = hole_centres(house, cfg, np.random.default_rng(1))
    assert len(centres) > 5
    rects = np.array([o["bbox"][:2] + o["bbox"][3:5] for o in house.meta["objects"] if o["support"] == "floor"])
    gap = np.maximum(np.maximum(rects[None, :, :2] - centres[:, None], centres[:, None] - rects[None, :, 2:]), 0)
    d = np.hypot(gap[..., 0], gap[..., 1]).min(axis=1)
    assert (d <= 0.46).all()   # within 45 cm of a piece of furniture (5-45 cm outside one, maybe inside its neighbour)


def test_floor_artifacts_on_a_floor_sheet(house):
    cfg = ScanningConfig(holes_per_m2=0.2, hole_radius_m=(0.2, 0.3), unlabelled_floor_fraction=0.35, floor_warp_m=0.06)
    v, t, cls, inst = _floor_grid(0, 0, 6, 6)
    out_v, out_t, out_c, out_i, counts = apply_floor_artifacts(house, v, t, cls, inst, cfg, np.random.default_rng(2))
    assert len(out_t) < len(t) and counts["holes_m2"] > 0.1                       # holes cut
    void = out_c == VOID
    assert 0.3 < counts["unlabelled_floor_fraction"] < 0.6 and void.any() and (out_i[void] == -1).all()
    assert 0.045 <= counts["warp_m"] <= 0.06
    lift = out_v[:, 2] - v[:, 2]
    assert lift.min() >= -1e-9 and lift.max() <= counts["warp_m"] + 1e-9 and lift.max() > 0.8 * counts["warp_m"]
    # low frequency: neighbouring vertices (10 cm apart) differ by far less than the amplitude
    grid = lift.reshape(61, 61)
    assert np.abs(np.diff(grid, axis=0)).max() < 0.25 * counts["warp_m"]


def test_warp_field_spans_zero_to_the_amplitude():
    f = warp_field(np.zeros(2), np.array([8.0, 6.0]), 0.05, ScanningConfig(), np.random.default_rng(3))
    xy = np.stack(np.meshgrid(np.linspace(0, 8, 81), np.linspace(0, 6, 61)), -1).reshape(-1, 2)
    z = f(xy)
    assert z.min() == pytest.approx(0.0, abs=1e-3) and z.max() == pytest.approx(0.05, abs=1e-3)


@pytest.mark.parametrize("key, value", [("rug_thickness_m", (0.03, 0.01)), ("hole_radius_m", (0.1,)),
                                        ("floor_warp_m", -0.01), ("unlabelled_floor_fraction", 1.5)])
def test_artifact_keys_refuse_bad_values(key, value):
    with pytest.raises(ValueError, match=key):
        ScanningConfig(**{key: value})
