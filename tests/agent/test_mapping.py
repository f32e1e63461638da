"""Agent map stages: ground-plane projection, goal detection, frontiers, collision marking."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from calnav.agent.collision import CollisionTracker, collision_points, is_collision
from calnav.agent.config import AgentConfig
from calnav.agent.exploration import choose_frontier, frontier_mask
from calnav.agent.goal_detection import detect_goal, largest_component
from calnav.agent.semantic_map import FusedMapBuilder, MapChannels, MapState, NdfMapBuilder
from calnav.agent.votes import VoxelVotes
from calnav.mapping.config import MappingConfig
from calnav.mapping.frame import SegmentedFrame
from calnav.envs.task import Action
from calnav.agent import projection as pj


def test_project_voxels_gives_per_cell_class_means():
    # cell size 1 m, 2x2 map at origin (0, 0); K = 3
    coords = np.array([[0.2, 0.2, 0.5], [0.7, 0.4, 1.0], [0.5, 0.5, 0.3], [1.5, 0.5, 0.5], [1.5, 1.5, 0.5]], np.float32)
    probs = np.array([[0.8, 0.1, 0.1],   # cell (0,0) class 0 conf 0.8
                      [0.6, 0.3, 0.1],   # cell (0,0) class 0 conf 0.6
                      [0.1, 0.9, 0.0],   # cell (0,0) class 1 conf 0.9
                      [0.2, 0.2, 0.6],   # cell row 0, col 1: class 2 conf 0.6
                      [0.5, 0.4, 0.1]], np.float32)  # cell row 1, col 1: class 0 conf 0.5
    m = pj.project_voxels(coords, probs, np.zeros(2), 1.0, 2)
    assert m.shape == (3, 2, 2)
    np.testing.assert_allclose(m[0, 0, 0], 0.7, atol=1e-6)
    np.testing.assert_allclose(m[1, 0, 0], 0.9, atol=1e-6)
    np.testing.assert_allclose(m[2, 0, 1], 0.6, atol=1e-6)
    np.testing.assert_allclose(m[0, 1, 1], 0.5, atol=1e-6)
    assert m[1].sum() == np.float32(0.9) and m[2, 0, 0] == 0


def test_incremental_fused_projection_matches_full_projection():
    """Re-voting voxels by difference equals projecting the final votes from scratch."""
    cfg = AgentConfig(map_size_m=2.0, cell_m=0.5)
    state = MapState.empty(np.zeros(2), cfg, 3)
    module = FusedMapBuilder(cfg, MappingConfig(voxel_size_m=0.05), ("a", "b", "c"))
    rng = np.random.default_rng(0)
    ijk = rng.integers(-15, 15, (40, 3))
    ijk = np.unique(ijk, axis=0)

    class FakeMap:   # the voxel map's side of the contract: frame_voxels and fused_probs
        def __init__(self):
            self.probs = np.zeros((len(ijk), 3), np.float32)
            self.frame_voxels = (np.zeros((0, 3), np.int32), np.zeros(0, np.int64))

        def fused_probs(self, flat):
            return self.probs[flat]

    fake = FakeMap()
    seen = np.zeros(len(ijk), bool)
    for rnd in range(3):  # every round changes the fused probs of a subset of voxels, in random order
        flat = rng.permutation(np.flatnonzero(rng.random(len(ijk)) < 0.6))
        p = rng.random((len(flat), 3))
        fake.probs[flat] = p / p.sum(axis=1, keepdims=True)
        seen[flat] = True
        fake.frame_voxels = (ijk[flat].astype(np.int32), flat)
        module._project_fused(state, fake)
    keys = ijk[seen]
    probs = fake.probs[seen]
    ref = pj.project_voxels(keys * 0.05, probs, state.origin, cfg.cell_m, state.size)
    np.testing.assert_allclose(state.semantic, ref, atol=1e-5)


def test_voxel_keys_decode_to_their_indices():
    """decode inverts encode over the key range, negative indices and both ends included, and
    sorting keys keeps each key with its own indices (the projection decodes sorted keys)."""
    lim = VoxelVotes.KEY_OFFSET
    ijk = np.array([[0, 0, 0], [1, -2, 3], [-lim, lim - 1, -1], [lim - 1, -lim, 0], [-5, -5, -5]], np.int64)
    np.testing.assert_array_equal(VoxelVotes.decode(VoxelVotes.encode(ijk)), ijk)
    keys = VoxelVotes.encode(ijk)
    order = np.argsort(keys)
    np.testing.assert_array_equal(VoxelVotes.decode(keys[order]), ijk[order])

def _numpy_vote(model: dict, keys, ijk, classes, conf, voxel_m, origin, cell_m, sums, counts, semantic) -> None:
    """The reference: the projection's vote update as numpy did it before the compiled kernel
    (votes in a dict; the difference binned with ``sparse_bin_sums``, applied in float32)."""
    n = int(round(sums.shape[1] ** 0.5))
    cells, inside = pj.cell_of((ijk * voxel_m)[:, :2], origin, cell_m, n)
    keys, cells, classes, conf = keys[inside], cells[inside], classes[inside], conf[inside]
    old = [model[k] for k in keys.tolist() if k in model]
    old_cells = np.array([o[0] for o in old], np.int64)
    old_cls = np.array([o[1] for o in old], np.int16)
    old_conf = np.array([o[2] for o in old], np.float32)
    model.update({k: (c, l, f) for k, c, l, f in zip(keys.tolist(), cells.tolist(), classes.astype(np.int16).tolist(),
                                                     conf.tolist())})
    ncell = n * n
    bins = np.concatenate([old_cls.astype(np.int64) * ncell + old_cells, classes.astype(np.int64) * ncell + cells])
    u, dsum, dcnt = pj.sparse_bin_sums(bins, np.concatenate([-old_conf, conf]),
                                       np.concatenate([-np.ones(len(old), np.int64), np.ones(len(keys), np.int64)]))
    flat_sums, flat_counts, flat_sem = sums.reshape(-1), counts.reshape(-1), semantic.reshape(-1)
    flat_sums[u] += dsum.astype(np.float32)
    flat_counts[u] += dcnt.astype(np.int32)
    flat_sem[u] = np.where(flat_counts[u] > 0, flat_sums[u] / np.maximum(flat_counts[u], 1), 0.0)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), frames=st.integers(1, 6), per_frame=st.integers(0, 120))
def test_voxel_votes_match_the_numpy_projection(seed, frames, per_frame):
    """Frames of voxel votes (keys unique and sorted, some outside the map, many voting again
    for another class): the compiled update keeps the same votes as a dictionary and the same
    sums, counts and semantic layer as the numpy update, bit for bit."""
    rng = np.random.default_rng(seed)
    k, n, voxel_m, cell_m = 2, 3, 0.05, 0.1   # few bins: many votes per bin
    origin = np.array([0.025, -0.075])
    votes, model = VoxelVotes(), {}
    got = [np.zeros((k, n * n), np.float32), np.zeros((k, n * n), np.int32), np.zeros((k, n, n), np.float32)]
    ref = [a.copy() for a in got]
    for _ in range(frames):
        ijk = np.unique(rng.integers((0, 0, 0), (8, 8, 3), size=(per_frame, 3)), axis=0)   # 192 voxels, 108 inside
        keys = VoxelVotes.encode(ijk)
        order = np.argsort(keys)
        keys, ijk = keys[order], ijk[order]
        classes = rng.integers(0, k, len(keys))
        conf = rng.uniform(1.0 / k, 1.0, len(keys)).astype(np.float32)
        votes.vote(keys, ijk, classes, conf, voxel_m, origin, cell_m, *got)
        _numpy_vote(model, keys, ijk, classes, conf, voxel_m, origin, cell_m, *ref)
        for a, b in zip(got, ref):
            assert a.dtype == b.dtype and a.tobytes() == b.tobytes()
        assert votes.keys.tolist() == sorted(model)
        assert list(zip(votes.cells.tolist(), votes.classes.tolist(), votes.conf.tolist())) == \
            [model[key] for key in sorted(model)]
    assert not votes._slot.any()   # scratch left clean


def test_voxel_votes_refuse_what_the_kernel_would_index_out_of_bounds():
    votes, ijk = VoxelVotes(), np.array([[1, 1, 0]])
    keys, conf = VoxelVotes.encode(ijk), np.array([0.9], np.float32)
    maps = (np.zeros((2, 9), np.float32), np.zeros((2, 9), np.int32), np.zeros((2, 3, 3), np.float32))
    with pytest.raises(ValueError, match=r"vote classes must be in \[0, 2\)"):
        votes.vote(keys, ijk, np.array([2]), conf, 0.05, np.zeros(2), 0.1, *maps)
    with pytest.raises(ValueError, match="disagree"):
        votes.vote(keys, ijk, np.array([0, 1]), conf, 0.05, np.zeros(2), 0.1, *maps)
    with pytest.raises(ValueError, match="disagree"):
        votes.vote(keys, ijk, np.array([0]), conf, 0.05, np.zeros(2), 0.1, *maps[:2], np.zeros((2, 9), np.float32))
    with pytest.raises(ValueError, match="contiguous"):
        votes.vote(keys, ijk, np.array([0]), conf, 0.05, np.zeros(2), 0.1, maps[0].astype(np.float64), *maps[1:])
    with pytest.raises(ValueError, match="unique and sorted"):
        votes.vote(keys.repeat(2), ijk.repeat(2, axis=0), np.array([0, 0]), conf.repeat(2), 0.05, np.zeros(2), 0.1,
                   *maps)
    votes.vote(keys, ijk, np.array([1]), conf, 0.05, np.zeros(2), 0.1, *maps)
    assert maps[2][1, 0, 0] == np.float32(0.9) and maps[1].sum() == 1


def test_goal_detection_threshold_components_and_min_area():
    conf = np.zeros((20, 20), np.float32)
    conf[2:4, 2:4] = 0.95          # 4 cells
    conf[10:14, 10:13] = 0.9       # 12 cells, the largest
    conf[15, 15] = 0.99            # 1 cell
    det = detect_goal(conf, 0.85, 4)
    assert det.found and det.area == 12 and det.mask[10:14, 10:13].all() and not det.mask[2, 2]
    assert not detect_goal(conf, 0.92, 5).found        # only the 4-cell and 1-cell components pass 0.92
    assert detect_goal(conf, 0.92, 4).area == 4
    assert not detect_goal(conf, 0.995, 1).found
    excl = np.zeros_like(conf, bool)
    excl[10:14, 10:13] = True
    assert detect_goal(conf, 0.85, 4, exclude=excl).area == 4
    mask, area = largest_component(np.zeros((5, 5), bool), 1)
    assert area == 0 and not mask.any()


def test_frontier_extraction_and_choice():
    n = 60
    explored = np.zeros((n, n), bool)
    explored[10:50, 10:30] = True            # explored room; unknown beyond
    trav = explored.copy()
    trav[10:50, 20] = False                  # a wall with a door gap
    trav[28:32, 20] = True
    front = frontier_mask(explored, trav)
    assert front[10:50, 29].all() and front[10, 15] and not front[30, 15]
    cfg = AgentConfig(frontier_min_cells=3, frontier_size_weight_m=0.0, cell_m=0.05)
    choice = choose_frontier(explored, trav, (30, 12), cfg)
    assert choice is not None
    r, c = choice.goal
    assert choice.mask[r, c] and front[r, c]
    # nearest frontier from (30, 12) is the left edge (col 10), not the far right edge
    assert c == 10
    excl = np.zeros_like(explored)
    excl[:, :20] = True
    assert choose_frontier(explored, trav, (30, 12), cfg, exclude=excl).goal[1] > 20


def test_collision_marking_and_untrap():
    cfg = AgentConfig()
    pts = collision_points(np.array([1.0, 2.0]), 0.0, cfg)
    assert (pts[:, 0] >= 1.0 + cfg.agent_radius_m - 1e-9).all()
    assert (pts[:, 0] <= 1.0 + cfg.agent_radius_m + cfg.collision_mark_length_m + 1e-9).all()
    assert np.abs(pts[:, 1] - 2.0).max() <= cfg.collision_mark_width_m / 2 + 1e-9
    pts = collision_points(np.zeros(2), np.pi / 2, cfg)       # heading +y
    assert (pts[:, 1] > 0).all()
    assert is_collision(np.zeros(2), np.array([0.05, 0.0]), int(Action.MOVE_FORWARD), 0.2)
    assert not is_collision(np.zeros(2), np.array([0.25, 0.0]), int(Action.MOVE_FORWARD), 0.2)
    assert not is_collision(np.zeros(2), np.zeros(2), int(Action.TURN_LEFT), 0.2)


def _blocked(tracker: CollisionTracker, action: int, collided: bool) -> None:
    tracker.record(action)
    tracker.observe(collided)


def test_blocks_count_across_turns_and_start_an_escape():
    """A planner that turns between blocked forwards is stuck all the same: the blocks since
    the last move count, turns do not reset them."""
    cfg = AgentConfig()
    tracker = CollisionTracker(cfg)
    for _ in range(cfg.untrap_after - 1):
        _blocked(tracker, int(Action.MOVE_FORWARD), True)
        _blocked(tracker, int(Action.TURN_LEFT), False)
    assert tracker.next_action() is None and tracker.blocked == cfg.untrap_after - 1
    _blocked(tracker, int(Action.MOVE_FORWARD), False)          # a forward that moved resets the count
    assert tracker.blocked == 0
    for _ in range(cfg.untrap_after):
        _blocked(tracker, int(Action.MOVE_FORWARD), True)
    assert tracker.escaping and tracker.routines == 1


def test_escape_tries_every_heading_until_one_moves():
    """turn, forward, turn, forward, ... until a forward moves; one more forward ends it."""
    cfg = AgentConfig()
    tracker = CollisionTracker(cfg)
    tracker.record(int(Action.MOVE_FORWARD))
    tracker.force()
    open_heading = 5                       # only the 5th heading tried is free
    heading, actions = 0, []
    while (a := tracker.next_action()) is not None:
        actions.append(a)
        tracker.record(a)
        if a == Action.TURN_LEFT:
            heading += 1
        tracker.observe(a == Action.MOVE_FORWARD and heading != open_heading)
    assert actions[:4] == [Action.TURN_LEFT, Action.MOVE_FORWARD, Action.TURN_LEFT, Action.MOVE_FORWARD]
    assert heading == open_heading and actions[-2:] == [Action.MOVE_FORWARD, Action.MOVE_FORWARD]
    assert not tracker.escaping
    tracker.force()                         # the next escape turns the other way
    assert tracker.next_action() == Action.TURN_RIGHT


def test_escape_is_bounded():
    cfg = AgentConfig(untrap_steps=10)
    tracker = CollisionTracker(cfg)
    tracker.force()
    n = 0
    while (a := tracker.next_action()) is not None:
        tracker.record(a)
        tracker.observe(a == Action.MOVE_FORWARD)   # every heading blocked
        n += 1
    assert n == 10 and not tracker.escaping


def test_map_module_marks_obstacles_and_explored_from_a_wall():
    cfg = AgentConfig(map_size_m=8.0)
    state = MapState.empty(np.zeros(2), cfg, 3)
    module = NdfMapBuilder(cfg, MappingConfig(voxel_size_m=0.05), ("a", "b", "c"))
    # camera at (0, 0, 0.88) looking along +x; a wall 2 m ahead fills the image
    pose = np.eye(4)
    pose[:3, :3] = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]])
    pose[:3, 3] = [0, 0, 0.88]
    k = np.array([[20.0, 0, 16], [0, 20.0, 12], [0, 0, 1]])
    depth = np.full((24, 32), 2.0, np.float32)
    logits = np.zeros((24, 32, 3), np.float32)  # uniform: softmax gives 1/3 per class
    frame = SegmentedFrame(depth, k, logits, np.zeros((24, 32, 3), np.uint8))
    module.update(state, frame, pose)
    obst = state.channels[MapChannels.OBSTACLE]
    wall_col = state.to_cell(np.array([2.0, 0.0]), cfg.cell_m)[1]
    assert obst[:, wall_col].any() and not obst[:, :wall_col - 1].any()
    r0, c0 = state.to_cell(np.array([1.0, 0.0]), cfg.cell_m)
    assert state.channels[MapChannels.EXPLORED][r0, c0]          # free ray in front of the wall
    assert not state.channels[MapChannels.EXPLORED][r0, state.to_cell(np.array([3.0, 0.0]), cfg.cell_m)[1]]
    assert state.traversable(cfg)[r0, c0]


def test_ndf_projection_keeps_max_over_time_of_thresholded_detections():
    cfg = AgentConfig(map_size_m=2.0, cell_m=0.5, ndf_pixel_threshold=0.6)
    state = MapState.empty(np.zeros(2), cfg, 2)
    module = NdfMapBuilder(cfg, MappingConfig(voxel_size_m=0.05), ("a", "b"))
    cells = np.array([0, 0, 1, 1])
    inside = np.ones(4, bool)
    module._project_ndf(state, np.array([[0.9, 0.1], [0.7, 0.3], [0.55, 0.45], [0.2, 0.8]]), cells, inside)
    sem = state.semantic.reshape(2, -1)
    np.testing.assert_allclose(sem[0, 0], 0.8)          # mean of 0.9 and 0.7
    assert sem[0, 1] == 0 and np.isclose(sem[1, 1], 0.8)  # 0.55 below the pixel threshold
    module._project_ndf(state, np.array([[0.65, 0.35]]), cells[:1], inside[:1])
    np.testing.assert_allclose(sem[0, 0], 0.8)          # max over time: a lower frame does not lower it


def test_floor_holes_hand_case():
    """A camera 1 m up, pitched 45 deg down, sees no depth: its principal ray meets the floor
    1 m ahead at z-depth sqrt(2); rays above the horizon never meet it."""
    from calnav.agent.projection import floor_holes
    from calnav.envs.task import camera_pose

    k = np.array([[10.0, 0, 5], [0, 10.0, 5], [0, 0, 1]])     # 11 x 11 pixels, centre (5, 5)
    pose = camera_pose(np.zeros(2), 0.0, 1.0, np.deg2rad(-45.0))
    depth = np.zeros((11, 11), np.float32)
    pts = floor_holes(depth, k, pose, 0.5, 5.0)
    centre = floor_holes(np.where(np.arange(121).reshape(11, 11) == 60, 0.0, 1.0).astype(np.float32), k, pose, 0.5, 5.0)
    np.testing.assert_allclose(centre, [[1.0, 0.0]], atol=1e-6)
    assert len(pts) == 121                                    # all rays meet the floor within 5 m here
    assert len(floor_holes(depth, k, pose, 0.5, 1.2)) < 121  # nearer than the principal ray's 1.41 m only
    level = camera_pose(np.zeros(2), 0.0, 1.0, 0.0)          # looking level: the upper half never meets it
    assert len(floor_holes(depth, k, level, 0.5, 100.0)) == 5 * 11


def test_holes_block_until_the_floor_is_seen():
    from calnav.agent.semantic_map import MapChannels
    from calnav.envs.task import camera_pose

    cfg = AgentConfig(map_size_m=8.0, hole_margin_m=0.3)
    module = NdfMapBuilder(cfg, MappingConfig(voxel_size_m=0.05), ("a", "b", "c"), (0.5, 5.0))
    k = np.array([[20.0, 0, 16], [0, 20.0, 12], [0, 0, 1]])
    pose = camera_pose(np.zeros(2), 0.0, 0.88, np.deg2rad(-30.0))
    v, u = np.mgrid[0:24, 0:32]
    ray = np.stack([(u - 16) / 20.0, (v - 12) / 20.0, np.ones_like(u, float)], -1) @ pose[:3, :3].T
    floor = np.where(ray[..., 2] < 0, -0.88 / np.minimum(ray[..., 2], -1e-9), 0.0)
    floor[(floor < 0.5) | (floor > 5.0)] = 0
    floor = floor.astype(np.float32)

    state = MapState.empty(np.zeros(2), cfg, 3)
    holed = floor.copy()
    holed[8:12, 10:20] = 0.0                      # a hole, with floor seen below it in the image
    module.project_geometry(state, holed, k, pose)
    hole = state.channels[MapChannels.HOLE]
    assert hole.any() and (state.obstacles() & hole).sum() == hole.sum()
    r, c = np.argwhere(hole)[0]
    module.project_geometry(state, floor, k, pose)   # the same view, floor everywhere: cleared for good
    assert not state.channels[MapChannels.HOLE][r, c] and state.channels[MapChannels.FLOOR][r, c]
    module.project_geometry(state, holed, k, pose)
    assert not state.channels[MapChannels.HOLE][r, c]

    occluded = MapState.empty(np.zeros(2), cfg, 3)  # something closer than 0.5 m fills the bottom: no floor below
    near = floor.copy()
    near[6:, :] = 0.0
    module.project_geometry(occluded, near, k, pose)
    assert not occluded.channels[MapChannels.HOLE].any()
    off = NdfMapBuilder(AgentConfig(map_size_m=8.0), MappingConfig(voxel_size_m=0.05), ("a", "b", "c"))
    fresh = MapState.empty(np.zeros(2), cfg, 3)
    off.project_geometry(fresh, holed, k, pose)
    assert not fresh.channels[MapChannels.HOLE].any()
