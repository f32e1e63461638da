"""NavGrid: free floor and erosion, thin/overhanging obstacles, motion, geodesic distances."""
from __future__ import annotations

import numpy as np
import pytest

from calnav.envs.config import EnvConfig
from calnav.envs.navigation import GeodesicField, NavGrid
from calnav.envs.primitives import MeshBuilder, box_room_scene
from calnav.envs.scene import Scene, Texture

CFG = EnvConfig()
R = CFG.agent_radius_m
CELL = CFG.nav_cell_m
WALL_T, WALL_H = 0.1, 2.5
DOOR_X = (1.0, 2.0)  # doorway in the wall y = 3 between the two rooms


def _walls(b: MeshBuilder, segments) -> None:
    for (x0, y0), (x1, y1) in segments:  # axis-aligned wall centre lines, WALL_T thick
        size = (abs(x1 - x0) + WALL_T, abs(y1 - y0) + WALL_T, WALL_H)
        b.add_box(((x0 + x1) / 2, (y0 + y1) / 2, WALL_H / 2), size, "wall", b.new_instance(), (200, 200, 190))


def l_shaped_scene():
    """Room A [0, 6] x [0, 3] and room B [0, 3] x [3, 7] (an L), joined by a 1 m doorway
    x in DOOR_X through the wall y = 3. Wall faces are WALL_T / 2 inside these bounds."""
    b = MeshBuilder("l_house")
    b.add_box((3, 1.5, -0.05), (6, 3, 0.1), "floor", b.new_instance(), (150, 120, 90), Texture.GRAIN, faces="+z")
    b.add_box((1.5, 5, -0.05), (3, 4, 0.1), "floor", b.new_instance(), (150, 120, 90), Texture.GRAIN, faces="+z")
    _walls(b, [((0, 0), (6, 0)), ((6, 0), (6, 3)), ((3, 3), (6, 3)), ((3, 3), (3, 7)), ((0, 7), (3, 7)),
               ((0, 0), (0, 7)), ((0, 3), (DOOR_X[0], 3)), ((DOOR_X[1], 3), (3, 3))])
    return b.build()


OBJECTS = (("chair", (1.5, 1.0), (0.5, 0.5, 0.9)), ("table", (0.5, -0.8), (1.0, 0.6, 0.75)))
POLE_XY = (-1.0, 1.0)        # between cell centres of the box room's grid (see test)
POLE_RADIUS = 0.015
LOW_SHELF = ((-2.0, -1.0), (0.6, 0.3), (0.45, 0.6))   # xy centre, xy size, z range: in the band
HIGH_SHELF = ((1.0, -1.9), (1.2, 0.2), (1.2, 1.4))     # above the agent: must not block


def furnished_room() -> Scene:
    """box_room_scene (6 x 4 m, walls' inner faces at x = +-3, y = +-2) with OBJECTS, a thin
    pole and two shelves."""
    room = box_room_scene(objects=OBJECTS)
    b = MeshBuilder("extras")
    b.add_cylinder((*POLE_XY, 0.0), POLE_RADIUS, 1.2, "plant", b.new_instance(), (30, 140, 30), segments=12)
    for (x, y), (sx, sy), (z0, z1) in (LOW_SHELF, HIGH_SHELF):
        b.add_box((x, y, (z0 + z1) / 2), (sx, sy, z1 - z0), "shelf", b.new_instance(), (120, 90, 60))
    extra = b.build()
    return Scene(
        name="furnished", vertices=np.vstack([room.vertices, extra.vertices]),
        triangles=np.vstack([room.triangles, extra.triangles + len(room.vertices)]),
        tri_class=np.concatenate([room.tri_class, extra.tri_class]),
        tri_instance=np.concatenate([room.tri_instance, extra.tri_instance + room.tri_instance.max() + 1]),
        tri_albedo=np.vstack([room.tri_albedo, extra.tri_albedo]),
        tri_texture=np.concatenate([room.tri_texture, extra.tri_texture]))


@pytest.fixture(scope="module")
def l_grid():
    return NavGrid.build(l_shaped_scene(), CFG)


@pytest.fixture(scope="module")
def room_grid():
    return NavGrid.build(furnished_room(), CFG)


def rect_distance(p: np.ndarray, centre, size) -> np.ndarray:
    """Distance from points (N, 2) to an axis-aligned rectangle (0 inside)."""
    d = np.abs(p - np.asarray(centre)) - np.asarray(size) / 2
    return np.hypot(*np.maximum(d, 0).T)


def room_clearance(p: np.ndarray) -> np.ndarray:
    """Distance from points (N, 2) of the furnished 6 x 4 m room to the nearest obstacle."""
    walls = np.minimum(3.0 - np.abs(p[:, 0]), 2.0 - np.abs(p[:, 1]))
    obstacles = [rect_distance(p, c, s[:2]) for _, c, s in OBJECTS]
    obstacles.append(np.hypot(*(p - POLE_XY).T) - POLE_RADIUS)
    obstacles.append(rect_distance(p, *LOW_SHELF[:2]))
    return np.minimum(walls, np.min(obstacles, axis=0))


# ------------------------------------------------------------ free space
def test_navigable_excludes_obstacles_dilated_by_radius(room_grid):
    g = room_grid
    cells = np.argwhere(np.ones(g.shape, dtype=bool))
    centres = g.to_world(cells)
    clearance = room_clearance(centres).reshape(g.shape)
    nav = g.navigable
    assert nav.any()
    assert clearance[nav].min() >= R - CELL / 4            # never closer than the radius (- 1.25 cm)
    assert nav[clearance >= R + CELL].all()                # and not over-eroded
    # grid layout: row = y, col = x, origin at the mesh's lower corner
    np.testing.assert_allclose(g.origin_xy, [-3.1, -2.1], atol=1e-6)
    assert g.shape == (int(np.ceil(4.2 / CELL)), int(np.ceil(6.2 / CELL)))


def test_thin_pole_and_shelves(room_grid):
    g = room_grid
    centres_x = g.origin_xy[0] + (np.arange(g.shape[1]) + 0.5) * CELL
    assert np.abs(centres_x - POLE_XY[0]).min() > POLE_RADIUS  # a single centre ray would miss it
    assert not g.is_navigable((POLE_XY[0] + 0.1, POLE_XY[1]))
    assert g.is_navigable((POLE_XY[0] + 0.3, POLE_XY[1]))
    assert not g.is_navigable(LOW_SHELF[0])     # floating at 0.45-0.6 m: in the agent's band
    assert g.is_navigable((HIGH_SHELF[0][0], -1.7))  # under a 1.2 m shelf, 0.3 m from the wall


def test_closed_room_is_an_island_of_its_own():
    b = MeshBuilder("two_rooms")
    b.add_box((0, 0, -0.05), (8, 3, 0.1), "floor", b.new_instance(), (100, 100, 100), faces="+z")
    _walls(b, [((-4, -1.5), (4, -1.5)), ((-4, 1.5), (4, 1.5)), ((-4, -1.5), (-4, 1.5)),
               ((4, -1.5), (4, 1.5)), ((1, -1.5), (1, 1.5))])  # closed wall: small room on the right
    g = NavGrid.build(b.build(), CFG)
    assert g.island_of((-2, 0)) == 0 and g.island_of((2.5, 0)) == 1   # both kept, the larger first
    assert np.isinf(g.geodesic_distance((-2, 0), (2.5, 0)))


def test_no_navigable_area_raises():
    b = MeshBuilder("closet")
    b.add_box((0, 0, -0.05), (0.3, 0.3, 0.1), "floor", b.new_instance(), (100, 100, 100), faces="+z")
    with pytest.raises(ValueError, match="no navigable area"):
        NavGrid.build(b.build(), CFG)
    b = MeshBuilder("no_floor")   # geometry only: nothing walkable, only a wall
    b.add_box((0, 0, 1.2), (3, 0.1, 2.4), "wall", b.new_instance(), (100, 100, 100), faces="-y +y")
    with pytest.raises(ValueError, match="no navigable area"):
        NavGrid.build(b.build(), CFG)


# ---------------------------------------------------------------- motion
def test_move_forward(room_grid):
    g = room_grid
    start = np.array([2.6, 0.0])
    assert g.is_navigable(start)
    new, moved = g.move_forward(start, 0.0, CFG.forward_step_m)  # towards the x = 3 wall
    assert not moved and np.array_equal(new, start)
    new, moved = g.move_forward(start, np.pi, CFG.forward_step_m)
    assert moved and np.linalg.norm(new - start) == pytest.approx(0.25, abs=1e-12)
    np.testing.assert_allclose(new, [2.35, 0.0], atol=1e-12)
    new, moved = g.move_forward(start, np.deg2rad(120), 0.25)
    np.testing.assert_allclose(new - start, 0.25 * np.array([-0.5, np.sqrt(3) / 2]), atol=1e-12)


def test_move_through_thin_wall_blocked(l_grid):
    a, b = np.array([0.5, 2.7]), np.array([0.5, 3.3])  # both navigable, the wall y = 3 between
    assert l_grid.is_navigable(a) and l_grid.is_navigable(b)
    new, moved = l_grid.move_forward(a, np.pi / 2, 0.6)
    assert not moved and np.array_equal(new, a)
    assert not l_grid.segment_navigable(a, b)


def test_cells_and_sampling(l_grid):
    g = l_grid
    rng = np.random.default_rng(0)
    pts = g.sample_navigable(rng, 200)
    assert pts.shape == (200, 2) and g.is_navigable(pts).all()
    rc = g.to_cell(pts)
    np.testing.assert_allclose(g.to_world(rc), pts, atol=1e-9)  # samples are cell centres
    assert isinstance(g.to_cell(pts[0]), tuple) and g.to_cell(pts[0]) == tuple(rc[0])
    assert not g.is_navigable((100.0, 100.0)) and not g.is_navigable((5.0, 5.0))  # off grid, outside L


# ------------------------------------------------------------- geodesics
START, GOAL = np.array([5.0, 1.5]), np.array([1.5, 5.5])


def hand_l_path(c: float) -> float:
    """Taut path from START to GOAL around the doorway's right jamb, whose wall ends in the
    corners J1 = (1.95, 2.95) and J2 = (1.95, 3.05): the agent keeps clearance c, so the path
    is a tangent from START to the circle (J1, c), an arc round it, 0.1 m straight up the
    jamb's end, an arc round (J2, c) and a tangent to GOAL."""
    jamb_x = DOOR_X[1] - WALL_T / 2
    j1, j2 = np.array([jamb_x, 3 - WALL_T / 2]), np.array([jamb_x, 3 + WALL_T / 2])

    def tangent_and_angle(p, centre, side):
        v = p - centre
        dist = np.linalg.norm(v)
        # the tangent point lies arccos(c / dist) away from the direction to p, on `side`
        return np.sqrt(dist**2 - c**2), np.arctan2(v[1], v[0]) + side * np.arccos(c / dist)

    t1, a1 = tangent_and_angle(START, j1, -1)   # passes below J1
    t2, a2 = tangent_and_angle(GOAL, j2, +1)    # leaves J2's circle on its upper-left
    def arc(a, b):  # length of the shorter arc between angles a and b
        return c * abs(np.angle(np.exp(1j * (b - a))))

    left = np.pi  # both arcs meet the straight part at angle 180 degrees (the jamb's -x side)
    arc1, arc2 = arc(a1, left), arc(left, a2)
    return float(t1 + arc1 + WALL_T + arc2 + t2)


def test_geodesic_l_shaped_path(l_grid):
    field = l_grid.geodesic_field(_goal_mask(l_grid, GOAL))
    expected = hand_l_path(R + CELL / 4)  # ~6.20 m (the clearance kept is R - CELL / 6 .. R + 5 CELL / 6)
    euclid = float(np.linalg.norm(GOAL - START))
    d = field.distance(START)
    assert d > 1.1 * euclid
    assert d == pytest.approx(expected, rel=0.03)
    assert field.path_length(START) == pytest.approx(expected, rel=0.01)
    assert l_grid.geodesic_distance(START, GOAL) == pytest.approx(d, abs=CELL)
    path = field.path(START)
    assert len(path) >= 3 and all(l_grid.segment_navigable(a, b) for a, b in zip(path[:-1], path[1:]))


def _goal_mask(g: NavGrid, xy) -> np.ndarray:
    m = np.zeros(g.shape, dtype=bool)
    m[g.to_cell(xy)] = True
    return m


def test_geodesic_accuracy_open_field():
    """16-connected grid distance in an empty 10 x 10 m grid: within 2.7 % of Euclidean at
    every heading (an 8-connected grid is 8 % off at 22.5 degrees)."""
    g = NavGrid(navigable=np.ones((200, 200), dtype=bool), origin_xy=np.zeros(2), cell_m=0.05)
    goal = np.array([0.025, 0.025])
    field = g.geodesic_field(_goal_mask(g, goal))
    ang = np.deg2rad(np.arange(0, 91, 2.5))
    pts = goal + 9.0 * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    ratio = field.distance(pts) / 9.0
    assert ratio.min() >= 0.999 and ratio.max() < 1.028
    assert field.distance(goal + [9.0 * np.cos(np.pi / 8), 9.0 * np.sin(np.pi / 8)]) < 9.0 * 1.03


def test_distance_zero_in_goal_inf_unreachable_continuous():
    nav = np.ones((60, 100), dtype=bool)
    nav[:, 50:53] = False  # a full-height wall: two components
    g = NavGrid(navigable=nav, origin_xy=np.array([10.0, -2.0]), cell_m=0.05)
    goal = np.zeros(nav.shape, dtype=bool)
    goal[20:30, 10:20] = True
    field = g.geodesic_field(goal)
    inside = g.to_world((25, 15)) + 0.02
    assert field.distance(inside) == 0.0
    assert field.distance(g.to_world((25, 80))) == np.inf          # other side of the wall
    assert field.distance((0.0, 0.0)) == np.inf                     # off the grid
    d = field.distance(g.to_world([[25, 40], [59, 0]]))
    assert d.shape == (2,) and np.isfinite(d).all()
    np.testing.assert_allclose(d[0], 21 * 0.05, atol=1e-9)         # 21 cells right of goal col 19
    # continuity: a small step changes the distance by about the step
    xs = g.to_world((25, 40))[0] + np.linspace(0, 0.2, 41)
    dd = field.distance(np.stack([xs, np.full_like(xs, g.to_world((25, 40))[1] + 0.013)], axis=1))
    assert np.abs(np.diff(dd)).max() < 0.0075
    with pytest.raises(ValueError, match="no path"):
        field.descent_point(g.to_world((25, 80)), 0.5)
    off = g.geodesic_field(~nav)  # goals only on non-navigable cells
    assert np.isinf(off.distances_m).all()


def test_descent_point_follows_path(l_grid):
    field = l_grid.geodesic_field(_goal_mask(l_grid, GOAL))
    d0 = field.distance(START)
    p = field.descent_point(START, 1.0)
    assert np.linalg.norm(p - START) <= 1.0 + 1e-9
    assert field.distance(p) == pytest.approx(d0 - 1.0, abs=3 * CELL)
    assert l_grid.segment_navigable(START, p)
    np.testing.assert_allclose(field.descent_point(START, 100.0), l_grid.to_world(l_grid.to_cell(GOAL)))
    np.testing.assert_array_equal(field.descent_point(GOAL, 1.0), GOAL)


def test_field_cache(l_grid):
    m = _goal_mask(l_grid, GOAL)
    f1 = l_grid.geodesic_field(m)
    assert l_grid.geodesic_field(m.copy()) is f1
    assert isinstance(f1, GeodesicField)
    assert l_grid.geodesic_field(m, use_cache=False) is not f1
    for x in np.linspace(0.5, 2.5, 10):  # evict by filling the LRU
        l_grid.geodesic_field(_goal_mask(l_grid, (x, 5.0)))
    assert l_grid.geodesic_field(m) is not f1
    with pytest.raises(ValueError, match="shape"):
        l_grid.geodesic_field(np.zeros((3, 3), dtype=bool))


def test_house_walls_block():
    """Regression: ray tests alone let the agent through walls whose top face coincides with
    the ceiling. Every wall surface point in the agent's height band must be off the grid."""
    from calnav.envs.scene import sample_surface
    from calnav.envs.scenes import load_scene

    scene = load_scene("house_val_0000")
    cfg = EnvConfig()
    nav = NavGrid.build(scene, cfg)
    wall = scene.tri_class == scene.class_names.index("wall")
    pts = sample_surface(scene.vertices[scene.triangles[wall]], 0.02, np.random.default_rng(1))
    pts = pts[(pts[:, 2] > cfg.navmesh.agent_max_climb_m) & (pts[:, 2] < cfg.agent_height_m)]
    assert not nav.is_navigable(pts[:, :2]).any()
