"""Procedural houses: determinism, layout bounds, closed rooms, furniture priors and placement."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from calnav.envs.house import ROOM_KINDS, HouseSpec, generate_house
from calnav.envs.semantics import CLASS_ID, CLASS_NAMES, GOAL_CATEGORIES, STRUCTURE_IDS

SPEC = HouseSpec()
N_HOUSES = 20
EPS = 1e-3   # geometric tolerance, metres


@pytest.fixture(scope="module")
def houses():
    return [generate_house(seed) for seed in range(N_HOUSES)]


def _instance_boxes(scene) -> dict[int, np.ndarray]:
    """{instance: (6,) xyz-min, xyz-max} of every furniture (non-structure) instance, from the mesh."""
    furniture = ~np.isin(scene.tri_class, STRUCTURE_IDS) & (scene.tri_instance >= 0)
    out = {}
    for inst in np.unique(scene.tri_instance[furniture]):
        v = scene.vertices[scene.triangles[scene.tri_instance == inst]].reshape(-1, 3)
        out[int(inst)] = np.concatenate([v.min(0), v.max(0)])
    return out


def _room_of(scene, x: float, y: float):
    return next((r for r in scene.rooms if r.contains(x, y)), None)


def test_same_seed_same_house_and_different_seeds_differ():
    a, b, c = generate_house(123), generate_house(123), generate_house(124)
    for name in ("vertices", "triangles", "tri_class", "tri_instance", "tri_albedo", "tri_texture"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.rooms == b.rooms and a.meta == b.meta
    assert a.vertices.shape != c.vertices.shape or not np.array_equal(a.vertices, c.vertices)


def test_layout_bounds(houses):
    for s in houses:
        assert SPEC.min_rooms <= len(s.rooms) <= SPEC.max_rooms
        area = sum(r.area for r in s.rooms)
        assert SPEC.min_floor_area_m2 <= area <= SPEC.max_floor_area_m2
        assert area == pytest.approx(s.meta["floor_area_m2"])
        assert {r.kind for r in s.rooms} <= set(ROOM_KINDS)
        for i, r in enumerate(s.rooms):      # rooms never overlap
            for q in s.rooms[i + 1:]:
                assert min(r.xmax, q.xmax) - max(r.xmin, q.xmin) <= EPS or min(r.ymax, q.ymax) - max(r.ymin, q.ymin) <= EPS
        wall_top = s.vertices[s.triangles[s.tri_class == CLASS_ID["wall"]]][..., 2].max()
        assert SPEC.wall_height_m[0] <= wall_top <= SPEC.wall_height_m[1]
        ceiling_z = s.vertices[s.triangles[s.tri_class == CLASS_ID["ceiling"]]][..., 2]
        np.testing.assert_allclose(ceiling_z, wall_top, atol=1e-4)
        assert s.vertices[:, 2].min() >= -SPEC.wall_thickness_m - EPS   # nothing below the floor slab


def test_structure_and_door_classes_present(houses):
    for s in houses:
        present = {CLASS_NAMES[c] for c in s.classes_present()}
        assert {"floor", "wall", "ceiling", "door"} <= present, s.name
        for inst in s.instance_ids():
            s.instance_class(int(inst))   # every instance has exactly one class


def test_rooms_are_closed_every_ray_hits(houses):
    import open3d as o3d

    rng = np.random.default_rng(0)
    for s in houses[:4]:
        rs = o3d.t.geometry.RaycastingScene()
        rs.add_triangles(o3d.core.Tensor(s.vertices), o3d.core.Tensor(s.triangles.astype(np.uint32)))
        dirs = rng.normal(size=(400, 3)).astype(np.float32)
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        for r in s.rooms:
            eye = np.array([(r.xmin + r.xmax) / 2, (r.ymin + r.ymax) / 2, 1.2], np.float32)
            rays = np.concatenate([np.broadcast_to(eye, dirs.shape), dirs], 1)
            t_hit = rs.cast_rays(o3d.core.Tensor(np.ascontiguousarray(rays)))["t_hit"].numpy()
            assert np.isfinite(t_hit).all(), f"{s.name}: rays escape from the {r.kind}"


def test_toilets_in_bathrooms_beds_in_bedrooms(houses):
    for s in houses:
        for cls, kind in (("toilet", "bathroom"), ("bed", "bedroom")):
            for inst in s.instance_ids(CLASS_ID[cls]):
                c = s.instance_triangles(int(inst)).reshape(-1, 3).mean(0)
                room = _room_of(s, c[0], c[1])
                assert room is not None and room.kind == kind, f"{s.name}: {cls} {inst} in {room}"
        kinds = [r.kind for r in s.rooms]
        by_kind = {k: {o["class"] for o in s.meta["objects"] if kinds[o["room"]] == k} for k in set(kinds)}
        if "bathroom" in kinds:
            assert "toilet" in by_kind["bathroom"]


def test_goal_categories_are_frequent(houses):
    counts = {c: sum(CLASS_ID[c] in s.classes_present() for s in houses) for c in GOAL_CATEGORIES}
    for c, n in counts.items():
        assert n >= 0.75 * len(houses), f"{c} appears in only {n}/{len(houses)} houses: {counts}"
    for s in houses:
        assert sum(CLASS_ID[c] in s.classes_present() for c in GOAL_CATEGORIES) >= 4


def test_furniture_does_not_overlap_or_leave_its_room(houses):
    for s in houses:
        boxes = _instance_boxes(s)
        assert len(boxes) >= 2 * len(s.rooms) - 2, f"{s.name}: only {len(boxes)} objects"
        floor_ids = [i for i, b in boxes.items() if b[2] < EPS]
        for k, i in enumerate(floor_ids):
            a = boxes[i]
            room = _room_of(s, (a[0] + a[3]) / 2, (a[1] + a[4]) / 2)
            assert room is not None
            assert (a[0] >= room.xmin - EPS and a[3] <= room.xmax + EPS and a[1] >= room.ymin - EPS
                    and a[4] <= room.ymax + EPS), f"{s.name}: instance {i} pokes into a wall"
            for j in floor_ids[k + 1:]:
                b = boxes[j]
                ox = min(a[3], b[3]) - max(a[0], b[0])
                oy = min(a[4], b[4]) - max(a[1], b[1])
                assert ox <= EPS or oy <= EPS, f"{s.name}: instances {i} and {j} overlap"
        for i, a in boxes.items():   # raised objects rest on another object's top, or hang on a wall
            if a[2] < EPS:
                continue
            cx, cy = (a[0] + a[3]) / 2, (a[1] + a[4]) / 2
            on_top = any(abs(b[5] - a[2]) < EPS and b[0] <= cx <= b[3] and b[1] <= cy <= b[4]
                         for j, b in boxes.items() if j != i)
            room = _room_of(s, cx, cy)
            on_wall = room is not None and min(a[0] - room.xmin, room.xmax - a[3], a[1] - room.ymin, room.ymax - a[4]) < EPS
            assert on_top or on_wall, f"{s.name}: instance {i} ({CLASS_NAMES[s.instance_class(i)]}) floats"


def test_doorways_are_kept_clear(houses):
    t = SPEC.wall_thickness_m
    for s in houses:
        boxes = _instance_boxes(s)
        door_verts = s.vertices[s.triangles[s.tri_class == CLASS_ID["door"]]].reshape(-1, 3)
        for d in s.meta["doors"]:
            lo, hi = d["span"]
            n_axis, u_axis = (0, 1) if d["axis"] == "x" else (1, 0)
            reach = t / 2 + SPEC.walk_gap_m   # passage box through the doorway, both sides
            for b in boxes.values():
                overlap_u = min(hi, b[3 + u_axis]) - max(lo, b[u_axis])
                overlap_n = min(d["coord"] + reach, b[3 + n_axis]) - max(d["coord"] - reach, b[n_axis])
                assert overlap_u <= EPS or overlap_n <= EPS or b[2] > d["height"], f"{s.name}: doorway blocked"
            inside = ((door_verts[:, u_axis] > lo + EPS) & (door_verts[:, u_axis] < hi - EPS)
                      & (np.abs(door_verts[:, n_axis] - d["coord"]) < reach))
            assert not inside.any(), f"{s.name}: a door leaf swings into its doorway"


def _reachable_rooms(scene, cell: float = 0.05, band=(0.1, 0.88), radius: float = 0.18):
    """Rasterise obstacles (any triangle reaching into the height band), erode free space by the
    agent radius; return per-room free area in the largest connected region, and its share."""
    x0 = min(r.xmin for r in scene.rooms) - 0.2
    y0 = min(r.ymin for r in scene.rooms) - 0.2
    nx = int((max(r.xmax for r in scene.rooms) + 0.2 - x0) / cell) + 1
    ny = int((max(r.ymax for r in scene.rooms) + 0.2 - y0) / cell) + 1
    tri = scene.vertices[scene.triangles]
    zlo, zhi = tri[..., 2].min(1), tri[..., 2].max(1)
    blocking = (zhi > band[0]) & (zlo < band[1])
    obst = np.zeros((nx, ny), bool)
    lo = np.floor((tri[blocking, :, :2].min(1) - [x0, y0]) / cell).astype(int)
    hi = np.floor((tri[blocking, :, :2].max(1) - [x0, y0]) / cell).astype(int)
    for (a, b), (c, d) in zip(lo, hi):
        obst[a:c + 1, b:d + 1] = True
    free = ndimage.distance_transform_edt(~obst) * cell > radius
    labels, n = ndimage.label(free)
    sizes = np.bincount(labels.ravel())[1:]
    main = labels == 1 + int(np.argmax(sizes))
    xs = x0 + (np.arange(nx) + 0.5) * cell
    ys = y0 + (np.arange(ny) + 0.5) * cell
    room_area = []
    for r in scene.rooms:
        ix = (xs > r.xmin) & (xs < r.xmax)
        iy = (ys > r.ymin) & (ys < r.ymax)
        room_area.append(main[np.ix_(ix, iy)].sum() * cell * cell)
    return room_area, main.sum() / free.sum()


def test_every_room_is_reachable(houses):
    for s in houses[:6]:
        room_area, share = _reachable_rooms(s)
        assert min(room_area) > 1.0, f"{s.name}: a room is cut off: {room_area}"
        assert share > 0.95, f"{s.name}: only {share:.2f} of the free floor is connected"


def test_reachability_check_can_fail():
    """A house whose doorways are walled up again must fail the reachability check."""
    from calnav.envs.primitives import MeshBuilder

    s = generate_house(3)
    b = MeshBuilder("sealed")
    b.add_mesh(s.vertices, s.triangles, "floor", 0, (0, 0, 0))
    for d in s.meta["doors"]:
        lo, hi = d["span"]
        centre = [d["coord"], (lo + hi) / 2, 1.0] if d["axis"] == "x" else [(lo + hi) / 2, d["coord"], 1.0]
        size = [0.1, hi - lo, 2.0] if d["axis"] == "x" else [hi - lo, 0.1, 2.0]
        b.add_box(centre, size, "wall", 1, (0, 0, 0))
    b.rooms = s.rooms
    room_area, share = _reachable_rooms(b.build())
    assert min(room_area) == 0.0 or share < 0.95


def test_triangle_budget(houses):
    # generation time is a bench figure (`calnav bench --only env`: env.house_gen_ms), not a unit test
    assert max(len(s.triangles) for s in houses) < 30_000


def test_spec_digest_and_impossible_spec():
    assert HouseSpec().digest() == HouseSpec().digest()
    assert HouseSpec(walk_gap_m=0.7).digest() != HouseSpec().digest()
    with pytest.raises(RuntimeError, match="no valid layout"):
        generate_house(0, HouseSpec(min_room_side_m=30.0, max_layout_tries=3))


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2**63 - 1))
def test_any_seed_gives_a_valid_house(seed):
    s = generate_house(seed)
    assert SPEC.min_rooms <= len(s.rooms) <= SPEC.max_rooms
    assert SPEC.min_floor_area_m2 <= sum(r.area for r in s.rooms) <= SPEC.max_floor_area_m2
    assert CLASS_ID["door"] in s.classes_present()
    assert all(o["room"] < len(s.rooms) for o in s.meta["objects"])


def test_fits_rule():
    """The placement rule that keeps rooms traversable, on a 4 x 3 m room with a 0.6 m gap."""
    from calnav.envs.furnish import fits
    from calnav.envs.scene import Room

    room, gap = Room("office", 0, 0, 4, 3), 0.6
    assert fits(np.array([0, 0, 1, 0.5]), room, [], [], gap)             # flush in a corner
    assert not fits(np.array([0.3, 0, 1.3, 0.5]), room, [], [], gap)     # a 0.3 m sliver to the wall
    assert not fits(np.array([0, 1, 4, 1.5]), room, [], [], gap)         # spans the room: cuts it in two
    assert not fits(np.array([-0.1, 0, 1, 0.5]), room, [], [], gap)      # pokes into the wall
    assert not fits(np.array([1.5, 0, 2.5, 0.5]), room, [np.array([0, 0, 1, 0.5])], [], gap)   # 0.5 m to an object
    assert fits(np.array([1.6, 0, 2.5, 0.5]), room, [np.array([0, 0, 1, 0.5])], [], gap)
    assert not fits(np.array([1.6, 0, 2.5, 0.5]), room, [], [np.array([2, 0, 3, 1])], gap)   # in a doorway zone
