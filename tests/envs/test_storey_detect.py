"""A scan's storeys found from its geometry (``envs.storey_detect``): calnav's houses, whose
storeys are known, are the hand-checked cases."""
import numpy as np
import pytest

from calnav.envs.config import DatasetConfig
from calnav.envs.scenes import load_scene
from calnav.envs.storey_detect import detect_storeys, storey_meta


@pytest.mark.parametrize("storeys", [1, 2, 3])
def test_the_storeys_of_calnavs_houses_are_found_and_the_roof_is_not_one(storeys):
    """A house's top is a large walkable surface with nothing above it: not a storey."""
    scene = load_scene("house_val_0000", DatasetConfig(storeys=storeys))
    found = detect_storeys(scene)
    assert len(found) == storeys
    np.testing.assert_allclose(found, scene.meta.get("storey_z", [0.0]), atol=0.05)
    meta = storey_meta(scene)
    assert (meta == {}) == (storeys == 1)
    if storeys > 1:
        assert meta["storey_height_m"] == pytest.approx(scene.meta["storey_height_m"], abs=0.05)


def test_a_raised_floor_below_the_storey_gap_is_the_same_storey():
    """A bed or a stage (walkable, under 2 m above the floor) does not make a storey."""
    from dataclasses import replace

    scene = load_scene("house_val_0001")
    lifted = scene.vertices.copy()
    lifted[:, 2] += 1.5    # the whole house 1.5 m up, then the original beside it: two floors 1.5 m apart
    both = replace(scene, vertices=np.concatenate([scene.vertices, lifted + [40.0, 0.0, 0.0]]),
                   triangles=np.concatenate([scene.triangles, scene.triangles + len(scene.vertices)]),
                   tri_class=np.concatenate([scene.tri_class] * 2), tri_instance=np.concatenate([scene.tri_instance] * 2),
                   tri_albedo=np.concatenate([scene.tri_albedo] * 2), tri_texture=np.concatenate([scene.tri_texture] * 2))
    assert len(detect_storeys(both)) == 1
