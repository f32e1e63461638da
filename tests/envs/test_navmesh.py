"""Navigable space as Habitat computes it (Recast's rules, geometry only): steps, slopes,
clearance, holes, unlabelled and warped floors, islands, and the env's motion agreeing with it."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from calnav.envs.config import EnvConfig, NavMeshConfig
from calnav.envs.navigation import NavGrid
from calnav.envs.navmesh import build_heightfield, build_navmesh
from calnav.envs.primitives import MeshBuilder
from calnav.envs.scene_check import narrow_passages
from tests.envs.worlds import floor_patch, scan_like, sofa_step_house, walls, warped_floor_house

CFG = EnvConfig()
R, CELL = CFG.agent_radius_m, CFG.nav_cell_m


def _room(name: str = "room", size=(5.0, 4.0)) -> MeshBuilder:
    b = MeshBuilder(name)
    walls(b, 0.0, 0.0, *size)
    return b


def test_unlabelled_floor_is_walkable():
    b = _room()
    floor_patch(b, 0, 0, 2.5, 4, cls=None)
    floor_patch(b, 2.5, 0, 5, 4, cls="floor")
    g = NavGrid.build(scan_like(b, "unlabelled"), CFG)
    assert g.is_navigable((1.0, 2.0)) and g.is_navigable((4.0, 2.0))
    assert g.stats["islands"] == 1


@pytest.mark.parametrize("step_m, connected", [(0.035, True), (0.15, True), (0.3, False)])
def test_floor_steps_up_to_the_climb_connect(step_m, connected):
    """Two floor levels meeting at x = 2.5: a step up to agent_max_climb_m (0.2 m) is walked
    over; a higher one splits the floor, and a surface more than one climb off the largest
    one's height is another level (a platform, a table top), not this storey's ground."""
    b = _room()
    floor_patch(b, 0, 0, 2.5, 4, 0.0)
    floor_patch(b, 2.5, 0, 5, 4, step_m)
    g = NavGrid.build(scan_like(b, "step"), CFG)
    low, high = np.array([1.0, 2.0]), np.array([4.0, 2.0])
    assert g.is_navigable(low) and g.is_navigable(high) == connected
    assert np.isfinite(g.geodesic_distance(low, high)) == connected
    if connected:   # the env's forward step crosses the step line exactly where the grid lets it
        xy, moved = g.move_forward(np.array([2.4, 2.0]), 0.0, 0.25)
        assert moved and g.floor_height(xy) == pytest.approx(step_m, abs=1e-6)
        assert g.floor_height((1.0, 2.0)) == pytest.approx(0.0, abs=1e-6)
    else:
        assert not g.segment_navigable(low, high)


def test_hole_is_not_walkable_and_eroded():
    b = _room()
    floor_patch(b, 0, 0, 5, 1.5)
    floor_patch(b, 0, 2.5, 5, 4)
    floor_patch(b, 0, 1.5, 2.0, 2.5)
    floor_patch(b, 3.0, 1.5, 5, 2.5)     # the hole: [2, 3] x [1.5, 2.5]
    g = NavGrid.build(scan_like(b, "hole"), CFG)
    assert not g.is_navigable((2.5, 2.0))
    assert not g.is_navigable((2.0 - R + 0.05, 2.0))    # closer than the radius to the hole's edge
    assert g.is_navigable((2.0 - R - 0.15, 2.0))
    assert np.isfinite(g.geodesic_distance((1.0, 2.0), (4.0, 2.0)))   # round the hole


@pytest.mark.parametrize("angle_deg, walkable", [(20.0, True), (40.0, True), (55.0, False)])
def test_slope(angle_deg, walkable):
    """A 2 m ramp at ``angle_deg``: walkable below agent_max_slope_deg (45)."""
    b = MeshBuilder("ramp")
    rise = 2.0 * np.tan(np.radians(angle_deg))
    verts = np.array([[0, 0, 0], [2, 0, rise], [2, 3, rise], [0, 3, 0]], float)
    b.add_mesh(verts, np.array([[0, 1, 2], [0, 2, 3]]), "floor", 0, (100, 100, 100))
    field = build_heightfield(scan_like(b, "ramp"), CFG)
    centre = 30 * int(np.ceil(2.0 / CELL)) + 20    # a column in the ramp's middle (row 30, col 20)
    spans = slice(field["start"][centre], field["start"][centre + 1])
    assert bool(field["area"][spans].any()) == walkable


@pytest.mark.parametrize("bottom_m, passable", [(0.8, False), (1.0, True)])
def test_clearance_under_a_shelf(bottom_m, passable):
    """A slab spanning the room at ``bottom_m``: the 0.88 m agent (0.9 m in 5 cm cells, standing
    on the floor's 5 cm cell) fits under 1.0 m, not under 0.8 m."""
    b = _room()
    floor_patch(b, 0, 0, 5, 4)
    b.add_box((2.5, 2.0, bottom_m + 0.05), (1.0, 4.0, 0.1), "shelf", b.new_instance(), (90, 60, 30))
    g = NavGrid.build(scan_like(b, "shelf"), CFG)
    assert g.is_navigable((2.5, 2.0)) == passable
    assert np.isfinite(g.geodesic_distance((0.8, 2.0), (4.2, 2.0))) == passable


@pytest.mark.parametrize("height_m, blocks", [(0.12, False), (0.35, True)])
def test_low_clutter_is_stepped_over(height_m, blocks):
    b = _room()
    floor_patch(b, 0, 0, 5, 4)
    b.add_box((2.5, 2.0, height_m / 2), (0.4, 0.4, height_m), None, -1, (40, 40, 40))
    g = NavGrid.build(scan_like(b, "clutter"), CFG)
    assert g.is_navigable((2.5, 2.0)) != blocks


def test_warped_unlabelled_floor_navigable_like_a_flat_one():
    scene = warped_floor_house()
    g = NavGrid.build(scene, CFG)
    flat = NavGrid.build(warped_floor_house(0.0), CFG)
    assert g.stats["islands"] == 1
    assert abs(g.navigable.sum() - flat.navigable.sum()) <= 0.01 * flat.navigable.sum()
    assert 0.0 < np.nanmax(g.floor_heights[g.navigable]) <= 0.0601


def test_islands_kept_by_area_not_only_the_largest():
    """A closed 2 x 2 m room beside the main one is kept as its own island; a 0.8 x 0.8 m closet
    is below region_min_size^2 cells after the erosion and dropped."""
    b = MeshBuilder("islands")
    for x0, y0, x1, y1 in ((0, 0, 5, 3), (5.2, 0.5, 7.2, 2.5), (7.8, 1.0, 8.6, 1.8)):
        floor_patch(b, x0, y0, x1, y1)
    walls(b, 0, 0, 5, 3)
    walls(b, 5.2, 0.5, 7.2, 2.5)
    walls(b, 7.8, 1.0, 8.6, 1.8)
    mesh = build_navmesh(scan_like(b, "islands"), CFG)
    assert mesh.stats["islands"] == 2 and mesh.stats["dropped_islands"] >= 1
    g = NavGrid.build(scan_like(b, "islands"), CFG)
    assert g.island_of((2.5, 1.5)) == 0 and g.island_of((6.2, 1.5)) == 1 and g.island_of((8.2, 1.4)) == -1
    assert np.isinf(g.geodesic_distance((2.5, 1.5), (6.2, 1.5)))


def test_table_tops_are_not_the_storey():
    b = _room()
    floor_patch(b, 0, 0, 5, 4)
    b.add_box((2.5, 2.0, 0.375), (2.5, 2.0, 0.75), "table", b.new_instance(), (120, 80, 50))
    g = NavGrid.build(scan_like(b, "table"), CFG)
    assert not g.is_navigable((2.5, 2.0)) and g.stats["islands"] == 1


def test_winding_of_closed_solids_and_scans():
    """On closed solids (procedural houses) a face's winding tells up from down; a scan's floor
    with every face flipped (a PLY converted by swapping axes) still counts as floor."""
    b = _room()
    floor_patch(b, 0, 0, 5, 4)
    scene = scan_like(b, "flipped")
    scene.triangles = np.ascontiguousarray(scene.triangles[:, ::-1])
    assert NavGrid.build(scene, CFG).is_navigable((2.5, 2.0))
    scene.meta["closed_solids"] = True
    with pytest.raises(ValueError, match="no navigable area"):
        NavGrid.build(scene, CFG)


def test_navmesh_settings_matter():
    b = _room()
    floor_patch(b, 0, 0, 2.5, 4, 0.0)
    floor_patch(b, 2.5, 0, 5, 4, 0.15)
    scene = scan_like(b, "climb")
    low_climb = dataclasses.replace(CFG, navmesh=NavMeshConfig(agent_max_climb_m=0.1))
    assert np.isfinite(NavGrid.build(scene, CFG).geodesic_distance((1, 2), (4, 2)))
    assert np.isinf(NavGrid.build(scene, low_climb).geodesic_distance((1, 2), (4, 2)))


@pytest.mark.parametrize("override, message", [
    ("env.navmesh.agent_max_climb_m=-0.1", "agent_max_climb_m"),
    ("env.navmesh.agent_max_slope_deg=90", "agent_max_slope_deg"),
    ("env.navmesh.cell_height_m=0", "cell_height_m"),
    ("env.nav_cell_m=0", "nav_cell_m"),
    ("env.navmesh.region_min_size=-1", "region_min_size"),
    ("env.navmesh.agent_max_climb_m=nan", "agent_max_climb_m"),
])
def test_navmesh_keys_out_of_range(override, message):
    from calnav.eval.config import ConfigError, load_config

    with pytest.raises(ConfigError, match=message):
        load_config(None, [override])


def test_sofa_step_house_passages_and_view():
    """The real scan's failure, rebuilt: the step in front of the sofa is walked over, the hole
    beside it is not, and every navigable spot within the view-point radius of the sofa lies
    0.75-1.0 m from it (so an agent that stops only within 0.75 m never stops there)."""
    scene = sofa_step_house()
    g = NavGrid.build(scene, CFG)
    assert g.stats["islands"] == 1
    on_step, below = np.array([3.4, 3.27]), np.array([3.4, 3.12])   # the cells either side of the step
    assert g.is_navigable(on_step) and g.floor_height(on_step) == pytest.approx(0.035, abs=1e-6)
    assert g.is_navigable(below) and g.floor_height(below) == pytest.approx(0.0, abs=1e-6)
    assert not g.is_navigable((1.9, 4.4))      # the hole
    cells = g.to_world(np.argwhere(g.navigable))
    sofa = np.maximum(np.maximum((2.4, 4.1) - cells, cells - (4.4, 5.0)), 0.0)   # distance to its footprint
    d = np.hypot(sofa[:, 0], sofa[:, 1])
    near = d[d <= 1.0]
    assert len(near) > 20 and near.min() > 0.74


def test_narrow_passage_reported():
    """Two rooms joined by a 0.3 m gap (the agent needs 2 (r + cell / 2) = 0.41 m): two islands
    and one passage of about 0.3 m between them."""
    b = MeshBuilder("gap")
    floor_patch(b, 0, 0, 8.1, 3)
    walls(b, 0, 0, 4, 3, gaps=[("+x", 1.35, 1.65)])
    walls(b, 4.1, 0, 8.1, 3, gaps=[("-x", 1.35, 1.65)])
    mesh = build_navmesh(scan_like(b, "gap"), CFG)
    assert mesh.stats["islands"] == 2
    rows = narrow_passages(mesh, R)
    assert len(rows) == 1
    assert rows[0]["width_m"] == pytest.approx(0.3, abs=2 * CELL) and rows[0]["needed_m"] == pytest.approx(0.41)
    assert rows[0]["kept"] and abs(rows[0]["at_xy"][0] - 4.05) < 0.2 and abs(rows[0]["at_xy"][1] - 1.5) < 0.2


def corridor_house():
    """A 4 x 3 m room with a chair, and a 3 m dead-end corridor 0.52 m wide off its +x wall: the
    navmesh keeps a two-cell strip along the corridor, which 0.25 m steps at 30 degree turns can
    follow only when the heading happens to line up with it."""
    b = MeshBuilder("corridor_house")
    floor_patch(b, 0, 0, 4, 3)
    floor_patch(b, 4, 1.24, 7, 1.76)
    walls(b, 0, 0, 4, 3, gaps=[("+x", 1.24, 1.76)])
    walls(b, 4.0, 1.24, 7, 1.76, gaps=[("-x", 1.24, 1.76)])
    chair = b.new_instance()
    b.add_box((0.5, 0.5, 0.45), (0.5, 0.5, 0.9), "chair", chair, (60, 90, 160))
    return scan_like(b, "corridor_house")


def test_generation_keeps_only_episodes_the_oracle_solves():
    from calnav.envs.episodes import generate_scene_episodes, goal_mask
    from calnav.envs.oracle import oracle_solves
    from calnav.envs.render import Camera, Renderer

    scene = corridor_house()
    cfg = dataclasses.replace(CFG, resolution=(64, 48))
    g = NavGrid.build(scene, cfg)
    assert g.is_navigable((6.0, 1.5)) and np.isfinite(g.geodesic_distance((6.0, 1.5), (2.0, 1.5)))
    field = g.geodesic_field(g.navigable & (np.hypot(*(g.to_world(np.argwhere(np.ones(g.shape, bool))) -
                                                      (2.0, 1.5)).T) < 0.3).reshape(g.shape))
    assert oracle_solves(g, cfg, np.array([3.0, 1.5]), 0.3, field)              # in the room: solvable
    assert not oracle_solves(g, cfg, np.array([6.0, 1.5]), np.radians(17), field)   # in the corridor: not
    report: dict = {}
    renderer = Renderer(scene, Camera.from_config(cfg))
    eps = generate_scene_episodes("corridor_house", scene, g, renderer.raycasting_scene, cfg, 30, seed=3, report=report)
    assert len(eps) == report["kept"] == 30 and report["drawn"] == report["kept"] + report["unsolvable"]
    assert report["unsolvable"] > 0
    for ep in eps:
        assert oracle_solves(g, cfg, ep.start_position, ep.start_yaw, g.geodesic_field(goal_mask(g, ep.goals)))
