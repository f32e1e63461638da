"""A habitat-lab episode file's starts and view points placed on calnav's navmesh as habitat-sim
places them (``envs.file_episodes``), checked against hand-computed cases on a small grid."""
import math

import numpy as np
import pytest

from calnav.envs.config import EnvConfig
from calnav.envs.episode_files import GoalObject, ObjectNavEpisode
from calnav.envs.file_episodes import cache_name, place_points, place_scene_episodes
from calnav.envs.navigation import NavGrid

CELL = 0.1


def _grid(navigable: np.ndarray, floor: float = 0.0) -> NavGrid:
    """Cells of CELL m from the origin; every navigable cell's floor at ``floor`` m."""
    heights = np.where(navigable, floor, np.nan).astype(np.float32)
    return NavGrid(navigable=navigable, origin_xy=np.zeros(2), cell_m=CELL, free=navigable.copy(),
                   floor_heights=heights, islands=np.where(navigable, 0, -1).astype(np.int32))


def _room() -> NavGrid:
    """A 1 m x 1 m navigable square (cells 0..9) inside a 4 m x 4 m grid."""
    nav = np.zeros((40, 40), bool)
    nav[:10, :10] = True
    return _grid(nav)


def test_a_point_on_the_navmesh_stays_and_others_snap_to_the_nearest_cell_centre():
    grid = _room()
    xy = np.array([[0.52, 0.47],     # navigable, at the floor: stays exactly
                   [0.52, 0.47],     # navigable, 0.3 m above it (within is_navigable's 0.5 m): stays
                   [0.52, 0.47],     # 0.6 m above: snapped to its own cell centre (0.55, 0.45, 0)
                   [1.50, 0.45],     # 0.5 m east of the square: to the edge cell (0.95, 0.45)
                   [3.20, 0.45]])    # 2.25 m east of the edge: outside habitat-sim's 2 m search box
    heights = np.array([0.0, 0.3, 0.6, 0.0, 0.0])
    placed, _, ok, moved = place_points(grid, xy, heights)
    assert ok.tolist() == [True, True, True, True, False]
    np.testing.assert_array_equal(placed[:2], xy[:2])
    assert moved[0] == moved[1] == 0.0
    np.testing.assert_allclose(placed[2], [0.55, 0.45])
    assert moved[2] == pytest.approx(math.sqrt(0.03 ** 2 + 0.02 ** 2 + 0.6 ** 2))
    np.testing.assert_allclose(placed[3], [0.95, 0.45])
    assert moved[3] == pytest.approx(0.55)


def test_a_point_more_than_4_m_above_the_floor_is_not_placed():
    grid = _room()
    _, _, ok, _ = place_points(grid, [[0.5, 0.5], [0.5, 0.5]], [3.9, 4.2])   # 4.2 m: another storey's
    assert ok.tolist() == [True, False]


def _episode(start, goals, rotation=(0.0, 0.0, 0.0, 1.0), height=0.0) -> ObjectNavEpisode:
    return ObjectNavEpisode(episode_id="e", scene_id="data/scene_datasets/x/s.glb", start_position=np.array(start),
                            start_rotation=list(rotation), object_category="chair", geodesic_distance=1.0,
                            euclidean_distance=1.0, goals=goals, start_height=height)


def _goal(points) -> GoalObject:
    pts = np.array(points, np.float64).reshape(-1, 2)
    return GoalObject(3, "chair", np.zeros(3), pts, np.zeros(len(pts)))


def test_episodes_are_placed_or_refused_with_their_reason():
    nav = np.zeros((40, 40), bool)
    nav[:10, :10] = True
    nav[:10, 30:] = True          # a second island, 2 m east of the first: no path between them
    grid = _grid(nav)
    cfg = EnvConfig()             # env.dataset.max_snap_m 0.5 m
    reachable, far = _goal([[0.5, 0.5], [3.9, 3.9]]), _goal([[3.5, 0.5]])
    tilt = (0.1, 0.0, 0.0, math.sqrt(1 - 0.01))
    episodes = [_episode([0.25, 0.25], [reachable]),          # placed as it is
                _episode([1.3, 0.25], [reachable]),           # 0.35 m off: snapped onto the square
                _episode([1.75, 0.25], [reachable]),          # 0.8 m off: beyond max_snap_m
                _episode([0.25, 0.25], [reachable], tilt),    # not a turn about the up axis
                _episode([0.25, 0.25], [_goal([[3.9, 3.9]])]),  # its one view point lies nowhere near the navmesh
                _episode([0.25, 0.25], [far])]                # its view point is on the other island
    placed, counts = place_scene_episodes(grid, episodes, cfg)
    reasons = [ep.refused.split(":")[0] for ep in placed]
    assert reasons == ["", "", "start off the navmesh", "tilted start", "no view point", "unreachable"]
    np.testing.assert_array_equal(placed[0].start_position, [0.25, 0.25])
    np.testing.assert_allclose(placed[1].start_position, [0.95, 0.25])
    assert "0.80 m away" in placed[2].refused
    assert counts["kept"] == 2 and counts["starts_snapped"] == 1 and counts["max_start_snap_m"] == pytest.approx(0.35)
    assert counts["refused"] == {"start off the navmesh": 1, "tilted start": 1, "no view point": 1, "unreachable": 1}
    # the shared goal is placed once: its (3.9, 3.9) view point dropped, (0.5, 0.5) kept
    assert placed[0].goals[0] is placed[1].goals[0]
    np.testing.assert_array_equal(placed[0].goals[0].view_points, [[0.5, 0.5]])
    assert counts["view_points"] == 4 and counts["view_points_dropped"] == 2


def test_cache_names_of_scenes_with_one_name_differ():
    a, b = cache_name("hm3d/val/00800-TEEsavR23oF/TEEsavR23oF.basis.glb"), cache_name("mine/TEEsavR23oF.glb")
    assert a.startswith("TEEsavR23oF-") and b.startswith("TEEsavR23oF-") and a != b
