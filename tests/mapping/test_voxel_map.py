"""The semantic voxel map (mapping.voxel_map) on a ray-cast box room: accuracy against ground
truth, agreement with the batched ``fuse`` through the observation cache, hashmap growth,
read-outs, memory and bad input."""
import numpy as np
import pytest
import torch

from calnav.envs.primitives import box_room_scene
from calnav.mapping.config import MappingConfig
from calnav.mapping.fusion import fuse
from calnav.mapping.glfs import GLFSParams
from calnav.mapping.ground_truth import LabelledMesh
from calnav.mapping.registry import FUSIONS
from calnav.mapping.calibration.obs_cache import ObsCache
from calnav.mapping.voxel_map import SemanticVoxelMap
from calnav.mapping.weighting import WeightingParams, sample_weights

W, H, HFOV_DEG = 160, 120, 79.0
# Shift the room by a fraction of a voxel so that no voxel centre lies exactly on two surfaces
# (on a grid-aligned room the nearest-triangle ground truth of edge voxels is an arbitrary tie).
SUBVOXEL_SHIFT = np.float32([0.013, 0.021, 0.017])
VIEWS = [((-2, 1, 0.88), (2, -1, 0.5)), ((2, 1.5, 1.2), (-2, -1, 0.3)), ((0, 0, 1.5), (2.5, 1.5, 0.5)),
         ((-2.5, -1.5, 1.0), (0, 1.5, 1.0)), ((2.5, -1.5, 0.9), (-1, 1.5, 0.2)), ((0, 1.5, 1.3), (0, -2, 0.4)),
         ((-1, -1.5, 1.6), (-2.5, 1.5, 0.0)), ((1, 0, 0.6), (-2, -1.2, 0.4))]


def intrinsics(w=W, h=H):
    f = w / 2 / np.tan(np.deg2rad(HFOV_DEG / 2))
    return np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])


def look_at(eye, target):
    """(4, 4) world-from-camera pose (OpenCV axes) at ``eye`` looking at ``target``, z up."""
    eye = np.asarray(eye, float)
    fwd = np.asarray(target, float) - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, (0, 0, 1.0))
    right /= np.linalg.norm(right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, np.cross(fwd, right), fwd, eye
    return pose


@pytest.fixture(scope="module")
def room():
    scene = box_room_scene()
    mesh = LabelledMesh(scene.vertices + SUBVOXEL_SHIFT, scene.triangles, scene.tri_class)
    k = intrinsics()
    frames = []
    for eye, target in VIEWS:
        pose = look_at(eye, target)
        depth, labels = mesh.render(k, pose, W, H)
        frames.append((depth, pose, labels))
    return scene, mesh, k, frames


def noisy_logits(labels, k_classes, rng, margin=2.0, fp16=True):
    """(H, W, K) logits: N(0, 1) plus ``margin`` on the true class; fp16-exact (the cache's
    precision) so that the map and a fuse over its cache see identical numbers."""
    z = rng.normal(size=labels.shape + (k_classes,)).astype(np.float32)
    hit = labels >= 0
    z[hit, labels[hit]] += margin
    return z.astype(np.float16).astype(np.float32) if fp16 else z


def onehot_logits(labels, k_classes, scale=10.0):
    z = np.zeros(labels.shape + (k_classes,), np.float32)
    hit = labels >= 0
    z[hit, labels[hit]] = scale
    return z


MIN_TEST_BLOCKS = 64
SMALL_ALLOC_MB = 48.0  # the room needs ~1200 blocks; tests need not allocate the 192 MB default


def build(scene, frames, logits_fn, **cfg):
    cfg = {"initial_alloc_mb": SMALL_ALLOC_MB} | cfg
    m = SemanticVoxelMap(scene.num_classes, MappingConfig(**cfg), class_names=scene.class_names)
    for depth, pose, labels in frames:
        m.integrate(depth, intrinsics(), pose, logits_fn(labels))
    return m


@pytest.mark.parametrize("fusion", FUSIONS.names())
def test_perfect_logits_label_the_box_room(room, fusion):
    scene, mesh, _, frames = room
    m = build(scene, frames, lambda lab: onehot_logits(lab, scene.num_classes), fusion=fusion)
    coords, probs = m.voxels()
    assert probs.shape == (len(coords), scene.num_classes) and np.allclose(probs.sum(1), 1, atol=1e-5)
    gt = mesh.voxel_labels(coords, max_dist_m=np.sqrt(3) * 0.05)
    assert (gt >= 0).mean() > 0.999  # semantic voxels lie on the surface
    acc = (probs.argmax(1) == gt)[gt >= 0].mean()
    assert acc >= 0.99, f"{fusion}: {acc:.4f}"
    assert len(coords) > 20000  # most of the ~100 m^2 of visible surface (400 voxels / m^2)


FUSE_CASES = [("rbu", "none"), ("averaging", "incidence"), ("histogram", "distance"),
              ("geometric_mean", "sweet_spot"), ("glfs", "auto"), ("averaging", "lut")]


@pytest.mark.parametrize("fusion,weighting", FUSE_CASES)
def test_incremental_map_matches_batched_fuse(room, fusion, weighting):
    """Same observations, two paths: index_add_ into voxel attributes vs fuse over the cache.
    A tiny initial block_count makes the hashmap grow (and reallocate) along the way."""
    scene, _, k, frames = room
    kk = scene.num_classes
    rng = np.random.default_rng(7)
    params = GLFSParams(tau=rng.uniform(0.5, 2.0, kk), g=0.35, eps=0.25, M=rng.uniform(0.0, 2.0, (kk, 5, 3)),
                        class_names=scene.class_names)
    cache = ObsCache(kk, 0.05, cap=None)
    cfg = MappingConfig(fusion=fusion, weighting=weighting, block_count=16)
    temperature = None if fusion == "glfs" else 1.7
    m = SemanticVoxelMap(kk, cfg, class_names=scene.class_names, glfs_params=params, temperature=temperature,
                         obs_cache=cache)
    for depth, pose, labels in frames:
        pixel_w = rng.choice(np.float32([0.5, 1.0, 2.0]), size=depth.shape)
        m.integrate(depth, k, pose, noisy_logits(labels, kk, rng), weights=pixel_w)
    assert m.vbg.hashmap().capacity() > 16  # it grew
    obs = cache.to_padded()
    tau = torch.from_numpy(params.tau) if fusion == "glfs" else torch.tensor(temperature)
    name = {"auto": "lut"}.get(weighting, weighting)
    w = sample_weights(name, (obs.logits / tau).argmax(-1), obs.distance_m, obs.angle_deg,
                       WeightingParams.from_config(cfg, lut=torch.from_numpy(params.M))) * obs.weight
    gates = {"g": params.g, "eps": params.eps} if fusion == "glfs" else {}
    batched = fuse(obs.logits, fusion, mask=obs.mask, weights=w, temperature=tau, **gates).numpy()
    incremental, observed = m.query(cache.coords)
    assert observed.all() and obs.mask.sum(1).max() >= 4
    np.testing.assert_allclose(incremental, batched, atol=1e-5, rtol=0)


def test_growth_keeps_results(room):
    scene, _, _, frames = room
    rng = np.random.default_rng(3)
    logits = [noisy_logits(lab, scene.num_classes, rng) for _, _, lab in frames]
    it = iter(logits * 2)
    big = build(scene, frames, lambda lab: next(it), fusion="rbu", block_count=4000)
    tiny = build(scene, frames, lambda lab: next(it), fusion="rbu", block_count=8)
    assert tiny.vbg.hashmap().capacity() > 8 and big.vbg.hashmap().capacity() == 4000
    (cb, pb), (ct, pt) = big.voxels(), tiny.voxels()
    ob, ot = np.lexsort(cb.T), np.lexsort(ct.T)
    np.testing.assert_array_equal(cb[ob], ct[ot])
    np.testing.assert_allclose(pb[ob], pt[ot], atol=1e-6)


def test_readouts(room):
    scene, mesh, k, frames = room
    rng = np.random.default_rng(5)
    m = build(scene, frames, lambda lab: noisy_logits(lab, scene.num_classes, rng, margin=4.0), fusion="averaging")
    depth, pose, labels = frames[0]
    probs, valid = m.render_semantics(k, pose, W, H)
    assert probs.shape == (H, W, scene.num_classes) and valid.mean() > 0.8
    assert np.allclose(probs[valid].sum(-1), 1, atol=1e-5) and (probs[~valid] == 0).all()
    seen = valid & (labels >= 0)
    assert (probs.argmax(-1)[seen] == labels[seen]).mean() > 0.95
    pc = m.point_cloud()
    assert len(pc.points) > 10000 and pc.colors.dtype == np.uint8 and pc.probs.shape == (len(pc.points), scene.num_classes)
    pc_gt = mesh.voxel_labels(pc.points, max_dist_m=0.05)
    assert (pc.probs.argmax(1) == pc_gt)[pc_gt >= 0].mean() > 0.95
    coords, _ = m.voxels()
    normals = m.voxel_normals(coords)
    floor = mesh.voxel_labels(coords, max_dist_m=0.087) == scene.class_names.index("floor")
    assert np.median(normals[floor, 2]) > 0.95  # outward normal of the floor is +z
    p, observed = m.query(np.array([[0.0, 0.0, 1.3], coords[0]]))
    assert not observed[0] and observed[1] and np.allclose(p[0], 1 / scene.num_classes)


def test_incidence_angles_of_a_tilted_plane():
    from calnav.mapping.frame_geometry import incidence_angles

    k = intrinsics(64, 48)
    v, u = np.mgrid[0:48, 0:64]
    ray = np.stack([(u - k[0, 2]) / k[0, 0], (v - k[1, 2]) / k[1, 1], np.ones_like(u, float)], -1)
    normal = np.array([0.0, -np.sin(0.6), -np.cos(0.6)])  # plane n . x = -2, tilted 0.6 rad
    depth = (-2.0 / (ray @ normal)).astype(np.float32)
    pix = np.arange(48 * 64)
    angle = incidence_angles(depth, k, pix, offset=1)
    cos = np.abs(ray.reshape(-1, 3) @ normal) / np.linalg.norm(ray.reshape(-1, 3), axis=1)
    expected = np.degrees(np.arccos(cos)).reshape(48, 64)
    angle = angle.reshape(48, 64)
    np.testing.assert_allclose(angle[1:-1, 1:-1], expected[1:-1, 1:-1], atol=0.02)  # central differences
    np.testing.assert_allclose(angle, expected, atol=0.6)  # one-sided at the image border
    depth[:, 30:] = 0  # invalid neighbours: one-sided differences at the border of the hole
    holed = incidence_angles(depth, k, pix, 2).reshape(48, 64)
    assert np.isfinite(holed).all()
    np.testing.assert_allclose(holed[2:-2, 2:28], expected[2:-2, 2:28], atol=0.1)


def test_rgb_and_invalid_depth(room):
    scene, _, k, frames = room
    depth, pose, labels = frames[0]
    m = SemanticVoxelMap(scene.num_classes, MappingConfig(fusion="histogram", initial_alloc_mb=SMALL_ALLOC_MB))
    bad = depth.copy()
    bad[:, : W // 2] = np.nan
    bad[:10] = np.inf
    bad[-10:] = 100.0
    rgb = np.full((H, W, 3), (200, 100, 50), np.uint8)
    m.integrate(bad, k, pose, onehot_logits(labels, scene.num_classes), rgb=rgb)
    coords, _ = m.voxels()
    assert len(coords) > 500
    cam = (coords - pose[:3, 3]) @ pose[:3, :3]  # camera frame: everything in the valid right half
    u = k[0, 0] * cam[:, 0] / cam[:, 2] + k[0, 2]
    assert (u > W // 2 - 2).all()
    assert np.abs(m.point_cloud().colors.astype(int) - (200, 100, 50)).max() <= 1
    empty = SemanticVoxelMap(scene.num_classes, MappingConfig(block_count=MIN_TEST_BLOCKS))
    empty.integrate(np.zeros_like(depth), k, pose, onehot_logits(labels, scene.num_classes))
    assert len(empty.voxels()[0]) == 0 and empty.render_semantics(k, pose, W, H)[1].sum() == 0


def test_memory_starts_small_and_grows_with_the_observed_area(room):
    scene, _, k, frames = room
    m = SemanticVoxelMap(scene.num_classes, MappingConfig(fusion="glfs"))
    assert m.memory_bytes(allocated=True) < 300 * 2 ** 20
    assert m.memory_bytes() == 0
    sizes = []
    for depth, pose, labels in frames[:3]:
        m.integrate(depth, k, pose, onehot_logits(labels, scene.num_classes))
        sizes.append(m.memory_bytes())
    assert 0 < sizes[0] <= sizes[1] <= sizes[2] <= m.memory_bytes(allocated=True)


def test_bad_input(room):
    scene, _, k, frames = room
    depth, pose, labels = frames[0]
    kk = scene.num_classes
    m = SemanticVoxelMap(kk, MappingConfig(block_count=MIN_TEST_BLOCKS))
    good = onehot_logits(labels, kk)
    cases = [
        (dict(logits=good[..., :-1]), "K = 17 classes, the map has 18"),
        (dict(logits=good[:-1]), "logits are 160x119 pixels but depth is 160x120"),
        (dict(logits=good.astype(np.float64)), "float32"),
        (dict(depth=depth.astype(np.float64)), "depth must be a \\(H, W\\) float32"),
        (dict(depth=depth[None]), "depth must be"),
        (dict(rgb=np.zeros((H, W, 3), np.float32)), "uint8"),
        (dict(weights=np.ones((H, W), np.float64)), "weights"),
        (dict(weights=-np.ones((H, W), np.float32)), ">= 0"),
        (dict(pose=pose * 1.1), "not a rigid transform"),
        (dict(pose=pose @ np.diag([1.0, 1.0, -1.0, 1.0])), "det"),
        (dict(pose=np.vstack([pose[:3], [0, 0, 1, 1]])), "last row"),
        (dict(pose=pose[:3]), "\\(4, 4\\)"),
        (dict(intrinsics=k[:2]), "intrinsics"),
        (dict(intrinsics=-k), "fx, fy > 0"),
        (dict(logits=np.full_like(good, np.nan)), "NaN"),
    ]
    for change, msg in cases:
        args = dict(depth=depth, intrinsics=k, pose=pose, logits=good) | change
        with pytest.raises(ValueError, match=msg):
            m.integrate(**args)
    with pytest.raises(ValueError, match="valid choices"):
        SemanticVoxelMap(kk, MappingConfig(fusion="bayes"))
    with pytest.raises(ValueError, match="valid choices"):
        SemanticVoxelMap(kk, MappingConfig(weighting="gauss"))
    with pytest.raises(ValueError, match="other classes"):
        SemanticVoxelMap(kk, MappingConfig(fusion="glfs"), class_names=scene.class_names,
                         glfs_params=GLFSParams.identity(kk, tuple(reversed(scene.class_names))))
    with pytest.raises(ValueError, match="glfs_params.tau"):
        SemanticVoxelMap(kk, MappingConfig(fusion="glfs"), temperature=2.0)
    with pytest.raises(ValueError, match="CPU"):
        SemanticVoxelMap(kk, device="CUDA:0")


def _snapshot(m: SemanticVoxelMap) -> dict:
    """Copies of every voxel attribute, the hashmap's keys and slots, and the frame count."""
    from calnav.mapping.voxel_map import BASE_ATTRS, SEM

    hm = m.vbg.hashmap()
    out = {name: m.vbg.attribute(name).numpy().copy() for name in [a for a, _ in BASE_ATTRS] + [SEM]}
    out["active"] = np.sort(hm.active_buf_indices().numpy().astype(np.int64))
    out["keys"] = hm.key_tensor().numpy()[out["active"]].copy()
    out["size"], out["capacity"], out["frames"] = hm.size(), hm.capacity(), m.frames_integrated
    return out


def _assert_same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        if isinstance(a[k], np.ndarray):
            assert a[k].shape == b[k].shape and a[k].tobytes() == b[k].tobytes(), k  # bit-identical
        else:
            assert a[k] == b[k], k


@pytest.mark.parametrize("bad", ["nan logits at one observed pixel", "inf logits", "tiny focal length",
                                 "huge focal length"])
def test_a_rejected_frame_leaves_the_map_bit_identical(room, bad):
    scene, _, k, frames = room
    kk = scene.num_classes
    m = SemanticVoxelMap(kk, MappingConfig(initial_alloc_mb=SMALL_ALLOC_MB), class_names=scene.class_names)
    depth0, pose0, labels0 = frames[0]
    m.integrate(depth0, k, pose0, onehot_logits(labels0, kk))
    depth, pose, labels = frames[1]          # another view: new blocks and new TSDF weights if it went in
    logits, intr = onehot_logits(labels, kk), k.copy()
    v, u = np.argwhere(depth > 0)[len(np.argwhere(depth > 0)) // 2]
    if bad.startswith("nan"):
        logits[v, u, 3] = np.nan
    elif bad.startswith("inf"):
        logits[v, u, 0] = np.inf
    elif bad.startswith("tiny"):             # fx = fy = 1e-3: a 180-degree view (41.8 TiB of candidate table)
        intr[0, 0] = intr[1, 1] = 1e-3
    else:                                    # a 0.01-degree view
        intr[0, 0] = intr[1, 1] = 1e6
    before = _snapshot(m)
    with pytest.raises(ValueError, match="NaN or inf" if "logits" in bad else r"field of view .* outside \(1, 179\)"):
        m.integrate(depth, intr, pose, logits)
    _assert_same(before, _snapshot(m))
    m.integrate(depth, k, pose, onehot_logits(labels, kk))  # the same frame, sound, still goes in
    assert m.frames_integrated == 2


def test_readouts_use_only_the_maps_storage_interface():
    """The seam between SemanticVoxelMap and its read-outs (mapping/map_readout.py): the
    read-outs touch only the documented storage interface, never the fusion internals (it used
    to be a mixin reaching into the host's private members)."""
    import ast
    from pathlib import Path

    import calnav.mapping.map_readout as readout
    from calnav.mapping.voxel_map import SemanticVoxelMap

    interface = {"cfg", "vbg", "num_classes", "frames_integrated", "attribute", "observation_counts",
                 "fused_probs", "flat_indices", "o3d_weight_threshold", "has_geometry"}
    tree = ast.parse(Path(readout.__file__).read_text())
    used = {n.attr for n in ast.walk(tree)
            if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name) and n.value.id == "vmap"}
    assert used and used <= interface, f"read-outs use {sorted(used - interface)} beyond the storage interface"
    assert all(hasattr(SemanticVoxelMap, name) for name in interface - {"cfg", "vbg", "num_classes",
                                                                       "frames_integrated"})


def test_a_reset_map_fuses_like_a_new_one_and_keeps_its_allocation(room):
    """``reset`` (the agent empties one map per episode instead of building one, which would
    pay Open3D's hashmap doublings again): after a reset the same frames give bit-identical
    attributes at every voxel, with the grown capacity kept."""
    scene, _, k, frames = room
    kk = scene.num_classes
    cfg = MappingConfig(fusion="glfs", initial_alloc_mb=2.0)   # small: the first frames must grow it
    fill = _filler(frames, k, kk, seed=3)

    reused = fill(SemanticVoxelMap(kk, cfg, class_names=scene.class_names))
    grown = reused.vbg.hashmap().capacity()
    fill(reused.reset())
    fresh = fill(SemanticVoxelMap(kk, cfg, class_names=scene.class_names))
    assert reused.vbg.hashmap().capacity() == grown
    assert reused.frames_integrated == len(frames)

    (a, ca), (b, cb) = _by_key(reused), _by_key(fresh)
    assert np.array_equal(ca, cb)
    for name in a:
        assert a[name].tobytes() == b[name].tobytes(), name
    # an empty map reads out nothing
    empty = SemanticVoxelMap(kk, cfg, class_names=scene.class_names)
    fill(empty).reset()
    assert empty.vbg.hashmap().size() == 0 and len(empty.voxels()[0]) == 0


def _filler(frames, k, num_classes: int, seed: int):
    """fill(map) -> map: integrates the room's frames with noisy logits (drawn once, so every
    map filled sees the same numbers)."""
    rng = np.random.default_rng(seed)
    logits = [noisy_logits(labels, num_classes, rng, fp16=False) for _, _, labels in frames]

    def fill(m: SemanticVoxelMap) -> SemanticVoxelMap:
        for (depth, pose, _), lg in zip(frames, logits):
            m.integrate(depth, k, pose, lg)
        return m
    return fill


def _by_key(m: SemanticVoxelMap) -> tuple[dict, np.ndarray]:
    """Every attribute's rows and the voxel coordinates of all allocated voxels, in coordinate
    order (buffer slots may differ between two maps of the same frames)."""
    from calnav.mapping.voxel_map import BASE_ATTRS, SEM

    coords, flat = (a.numpy() for a in m.vbg.voxel_coordinates_and_flattened_indices())
    order = np.lexsort(coords.T)
    names = [a for a, _ in BASE_ATTRS if m.has_geometry] + [SEM]
    return {name: m.attribute(name)[flat[order]] for name in names}, coords[order]


def test_a_semantics_only_map_fuses_the_same_semantics_and_refuses_geometry(room):
    """``tsdf=False`` (the agent's map): only the blocks holding semantic observations (a strict
    subset of the TSDF map's, which also covers the band around the surface), bit-identical
    semantic accumulators in them, no geometry at all, and every read-out that needs the
    surface refuses the map instead of reading it as empty; ``observed_voxels`` and
    ``query_keys`` read both maps alike."""
    scene, _, k, frames = room
    kk = scene.num_classes
    cfg = MappingConfig(fusion="glfs", initial_alloc_mb=SMALL_ALLOC_MB)
    fill = _filler(frames, k, kk, seed=5)

    full = fill(SemanticVoxelMap(kk, cfg, class_names=scene.class_names))
    sem = fill(SemanticVoxelMap(kk, cfg, class_names=scene.class_names, tsdf=False))
    (a, ca), (b, cb) = _by_key(full), _by_key(sem)
    row = {c.tobytes(): i for i, c in enumerate(ca)}
    same = np.array([row[c.tobytes()] for c in cb])   # every voxel of the semantics-only map is in the full one
    assert a["semantic"][same].tobytes() == b["semantic"].tobytes()
    rest = np.setdiff1d(np.arange(len(ca)), same)
    assert len(rest) > 0 and not a["semantic"][rest].any()   # the blocks it skips hold no observation
    counts = sem.vbg.attribute("semantic").numpy()[..., -1].reshape(sem.vbg.hashmap().capacity(), -1)
    active = sem.vbg.hashmap().active_buf_indices().numpy().astype(np.int64)
    assert (counts[active] > 0).any(axis=1).all()   # each allocated block holds an observation
    assert a["weight"].any() and set(b) == {"semantic"}   # no TSDF buffers at all
    assert sem.bytes_per_block < full.bytes_per_block
    assert full.has_geometry and not sem.has_geometry
    keys = np.rint(ca[::31] / cfg.voxel_size_m).astype(np.int32)
    for x, y in zip(full.query_keys(keys), sem.query_keys(keys)):   # what the agent reads: the same
        assert x.tobytes() == y.tobytes()
    for read in (sem.voxels, sem.point_cloud, lambda: sem.voxel_normals(ca[:5]),
                 lambda: sem.render_semantics(k, frames[0][1], W, H)):
        with pytest.raises(ValueError, match="semantics without the TSDF"):
            read()
    (c1, p1), (c2, p2) = full.observed_voxels(), sem.observed_voxels()
    o1, o2 = np.lexsort(c1.T), np.lexsort(c2.T)
    assert len(c1) > 0 and c1[o1].tobytes() == c2[o2].tobytes() and p1[o1].tobytes() == p2[o2].tobytes()
    surface, _ = full.voxels()   # the TSDF band keeps (nearly) all observed voxels
    assert len(c1) >= len(surface) > 0.9 * len(c1)


@pytest.mark.parametrize("tsdf", [True, False])
def test_frame_voxels_are_exactly_the_voxels_a_frame_fused_into(room, tsdf):
    """``frame_voxels`` after each integrate: the keys and buffer rows of the voxels whose
    observation count went up (what the agent re-projects), unique; empty after a frame without
    logits and after ``reset``."""
    scene, _, k, frames = room
    kk = scene.num_classes
    m = SemanticVoxelMap(kk, MappingConfig(fusion="glfs", initial_alloc_mb=SMALL_ALLOC_MB), tsdf=tsdf)
    rng = np.random.default_rng(3)
    for depth, pose, labels in frames[:3]:
        before = _counts_by_key(m)
        m.integrate(depth, k, pose, noisy_logits(labels, kk, rng, fp16=False))
        keys, flat = m.frame_voxels
        grew = _grown(before, _counts_by_key(m))
        # the same keys, each once (grew is unique: one entry per allocated voxel)
        assert len(keys) == len(grew) > 0 and np.array_equal(np.sort(_key_codes(keys)), grew)
        np.testing.assert_array_equal(m.flat_indices(keys), flat)
    m.integrate(frames[0][0], k, frames[0][1])   # geometry only
    assert len(m.frame_voxels[0]) == 0
    m.integrate(frames[1][0], k, frames[1][1], noisy_logits(frames[1][2], kk, rng, fp16=False))
    assert len(m.reset().frame_voxels[1]) == 0


_KEY_BITS, _KEY_OFFSET = 21, 1 << 20   # a voxel key's coordinates as one int64 (|key| < 2**20 voxels)


def _key_codes(keys) -> np.ndarray:
    """Integer voxel keys (N, 3) as one int64 each, the same code for the same key."""
    k = np.asarray(keys, np.int64) + _KEY_OFFSET
    assert ((k >= 0) & (k < 1 << _KEY_BITS)).all()
    return (k[:, 0] << (2 * _KEY_BITS)) | (k[:, 1] << _KEY_BITS) | k[:, 2]


def _counts_by_key(m: SemanticVoxelMap) -> tuple[np.ndarray, np.ndarray]:
    """(the key codes of every allocated voxel, sorted; their observation counts), (N,) each."""
    coords, flat = (a.numpy() for a in m.vbg.voxel_coordinates_and_flattened_indices())
    codes = _key_codes(np.rint(coords / m.cfg.voxel_size_m))
    order = np.argsort(codes, kind="stable")
    return codes[order], m.observation_counts(flat)[order]


def _grown(before: tuple[np.ndarray, np.ndarray], after: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The sorted key codes whose count went up from ``before`` to ``after`` (absent before: 0)."""
    (cb, nb), (ca, na) = before, after
    assert (np.diff(ca) > 0).all()   # sorted: one entry per allocated voxel
    at = np.minimum(np.searchsorted(cb, ca), max(len(cb) - 1, 0))
    prev = np.where(cb[at] == ca, nb[at], 0) if len(cb) else np.zeros_like(na)
    return ca[na > prev]
