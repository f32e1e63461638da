"""agent.segmenters: registry, shapes / dtypes, determinism, bad input, the gt confidence, the
noisy error model's properties (per-instance consistency across nearby views, more errors far
away, overconfidence) and the layout rule (agent code does not import envs)."""
import hashlib
import json
import subprocess
import sys

import numpy as np
import pytest
import torch

from calnav.agent.segmenters import BUILTIN_SEGMENTERS, SegmenterConfig, make_segmenter
from calnav.common.registry import Registry

SEGMENTER_NAMES = ("gt", "noisy", "learned_rgb", "learned_rgbd")   # the built-ins in the simulator's classes
from calnav.agent.segmenters.base import WEIGHTS_DIR, default_class_names
from calnav.agent.segmenters.learned import LEARNED_MODELS, default_weights_path, save_weights
from calnav.agent.segmenters.network import NetSpec, SegNet
from calnav.envs.render import camera_pose
from calnav.envs.semantics import CLASS_NAMES, GOAL_CATEGORIES, STRUCTURE_CLASSES, class_id

K = len(CLASS_NAMES)
RES = (64, 48)


def softmax(z):
    e = np.exp(z - z.max(-1, keepdims=True))
    return e / e.sum(-1, keepdims=True)


@pytest.fixture(scope="session")
def frames(small_env_config):
    """Four rendered 64x48 val frames with instance images and poses."""
    from calnav.eval.segmenter.data import SegDataConfig, render_frames

    return render_frames(small_env_config, SegDataConfig(resolution=RES, scenes=1, walk_steps=2), "val",
                         frames=4, seed=3, with_instance=True, progress=False)


@pytest.fixture(scope="session")
def weight_files(tmp_path_factory):
    """Untrained (random) weight files for both networks, at the 64x48 'training' resolution."""
    out = {}
    torch.manual_seed(0)
    for model in LEARNED_MODELS:
        net = SegNet(NetSpec(num_classes=K, in_depth=model == "learned_rgbd")).eval()
        out[model] = save_weights(net, tmp_path_factory.mktemp("w") / f"{model}.pt", model, CLASS_NAMES, RES)
    return out


def build(name, weight_files, **overrides):
    cfg = SegmenterConfig(weights=str(weight_files[name]) if name in weight_files else "", **overrides)
    return make_segmenter(name, cfg, "cpu")


def inputs(frames, i=0):
    return dict(semantic=frames.labels[i], instance=frames.instance[i], pose=frames.poses[i].astype(np.float64))


# ---------------------------------------------------------------------------------- registry
def test_registry_names_and_unknown_name():
    assert tuple(BUILTIN_SEGMENTERS) == (*SEGMENTER_NAMES, "hf", "onnx")
    # the shared Registry, as every other named part: one description per built-in, the key it is chosen by
    assert isinstance(BUILTIN_SEGMENTERS, Registry) and BUILTIN_SEGMENTERS.key == "agent.segmenter"
    assert all(BUILTIN_SEGMENTERS.describe().values())
    with pytest.raises(ValueError, match="unknown segmenter 'segformer'; valid: gt, noisy, learned_rgb, learned_rgbd, "
                                         "hf, onnx, or a factory as package.module:function"):
        make_segmenter("segformer")


def test_shipped_class_list_matches_simulator():
    assert default_class_names() == CLASS_NAMES


def test_cuda_request_without_cuda_is_a_clear_error(weight_files):
    if torch.cuda.is_available():
        pytest.skip("CUDA is available here")
    for name in SEGMENTER_NAMES:
        with pytest.raises(ValueError, match="CUDA is not available"):
            make_segmenter(name, SegmenterConfig(weights=str(weight_files.get(name, ""))), "cuda")


# ----------------------------------------------------------------------- shapes / determinism
@pytest.mark.parametrize("name", SEGMENTER_NAMES)
def test_shapes_dtypes_batch_and_determinism(name, frames, weight_files):
    seg = build(name, weight_files)
    assert seg.class_names == CLASS_NAMES and seg.num_classes == K
    rgb, depth = frames.rgb, frames.depth.astype(np.float32)
    kw = inputs(frames)
    out = seg(rgb[0], depth[0], **kw)
    assert out.shape == (RES[1], RES[0], K) and out.dtype == np.float32 and np.isfinite(out).all()
    np.testing.assert_array_equal(out, seg(rgb[0], depth[0], **kw))               # deterministic
    np.testing.assert_array_equal(out, build(name, weight_files)(rgb[0], depth[0], **kw))  # fresh instance too
    batch = seg.segment_batch(rgb[:3], depth[:3], semantic=frames.labels[:3], instance=frames.instance[:3],
                              poses=frames.poses[:3].astype(np.float64))
    assert batch.shape == (3, RES[1], RES[0], K) and batch.dtype == np.float32
    np.testing.assert_allclose(batch[0], out, atol=1e-4)


def test_learned_resizes_other_input_sizes(frames, weight_files):
    seg = build("learned_rgbd", weight_files)
    big_rgb = frames.rgb[0].repeat(2, 0).repeat(2, 1)
    big_depth = frames.depth[0].astype(np.float32).repeat(2, 0).repeat(2, 1)
    out = seg(big_rgb, big_depth)
    assert out.shape == (2 * RES[1], 2 * RES[0], K)
    native = build("learned_rgbd", weight_files, resolution=(2 * RES[0], 2 * RES[1]))(big_rgb, big_depth)
    assert native.shape == out.shape



@pytest.mark.parametrize("name", LEARNED_MODELS)
def test_traced_network_gives_the_eager_logits_bit_for_bit(name, frames, weight_files):
    """segmenter.trace (default on) runs one TorchScript trace per input shape; its logits equal
    eager mode's exactly, for single frames, a batch and a second resolution (a second trace)."""
    traced, eager = build(name, weight_files), build(name, weight_files, trace=False)
    assert traced.cfg.trace and not eager.cfg.trace
    rgb, depth = frames.rgb, frames.depth.astype(np.float32)
    for i in range(2):
        np.testing.assert_array_equal(traced(rgb[i], depth[i]), eager(rgb[i], depth[i]))
    np.testing.assert_array_equal(traced.segment_batch(rgb[:3], depth[:3]), eager.segment_batch(rgb[:3], depth[:3]))
    big = build(name, weight_files, resolution=(2 * RES[0], 2 * RES[1]))
    big_eager = build(name, weight_files, resolution=(2 * RES[0], 2 * RES[1]), trace=False)
    np.testing.assert_array_equal(big(rgb[0], depth[0]), big_eager(rgb[0], depth[0]))
    assert len(traced._traces) == 2 and not eager._traces   # (1, ...) and (3, ...) inputs


# --------------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("name", SEGMENTER_NAMES)
def test_bad_images(name, frames, weight_files):
    seg = build(name, weight_files)
    rgb, depth, kw = frames.rgb[0], frames.depth[0].astype(np.float32), inputs(frames)
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        seg(rgb[..., 0], depth, **kw)
    with pytest.raises(ValueError, match="uint8"):
        seg(rgb.astype(np.float32), depth, **kw)
    with pytest.raises(ValueError, match="depth must be"):
        seg(rgb, depth[:-1], **kw)
    with pytest.raises(ValueError, match="float metres"):
        seg(rgb, (depth * 1000).astype(np.uint16), **kw)


@pytest.mark.parametrize("name", ["learned_rgbd", "noisy"])
def test_depth_required(name, frames, weight_files):
    with pytest.raises(ValueError, match="needs depth"):
        build(name, weight_files)(frames.rgb[0], None, **inputs(frames))


def test_rgb_network_runs_without_depth(frames, weight_files):
    assert build("learned_rgb", weight_files)(frames.rgb[0]).shape == (RES[1], RES[0], K)


@pytest.mark.parametrize("name", ["gt", "noisy"])
def test_ground_truth_segmenters_need_semantic(name, frames):
    seg = make_segmenter(name)
    with pytest.raises(ValueError, match="'semantic'.*env's semantic observation"):
        seg(frames.rgb[0], frames.depth[0].astype(np.float32))
    with pytest.raises(ValueError, match="semantic must be"):
        seg(frames.rgb[0], frames.depth[0].astype(np.float32), semantic=frames.labels[0][:-1])


def test_missing_weights_name_path_and_command(tmp_path):
    missing = tmp_path / "nope.pt"
    with pytest.raises(FileNotFoundError) as info:
        make_segmenter("learned_rgb", SegmenterConfig(weights=str(missing)))
    assert str(missing) in str(info.value)
    assert f"calnav train-segmenter --segmenter learned_rgb --output {missing}" in str(info.value)


def test_weights_for_the_other_model_are_refused(weight_files):
    with pytest.raises(ValueError, match="not 'learned_rgb'"):
        make_segmenter("learned_rgb", SegmenterConfig(weights=str(weight_files["learned_rgbd"])))


def test_learned_weights_are_matched_to_calnav_classes_by_name(tmp_path, frames):
    """A weight file naming its network's outputs in another order than calnav's gives that
    network's logits in calnav's order; one naming a class twice, or one calnav lacks, is
    refused when it is checked (preflight) and when it is loaded."""
    torch.manual_seed(1)
    net = SegNet(NetSpec(num_classes=K)).eval()
    ordered = save_weights(net, tmp_path / "ordered.pt", "learned_rgb", CLASS_NAMES, RES)
    backwards = save_weights(net, tmp_path / "backwards.pt", "learned_rgb", CLASS_NAMES[::-1], RES)
    a = make_segmenter("learned_rgb", SegmenterConfig(weights=str(ordered)))
    b = make_segmenter("learned_rgb", SegmenterConfig(weights=str(backwards)))
    assert a.class_names == b.class_names == CLASS_NAMES and a.channels is None
    np.testing.assert_array_equal(b(frames.rgb[0]), a(frames.rgb[0])[..., ::-1])
    from calnav.agent.segmenters.learned import check_weights

    for names, match in [((*CLASS_NAMES[:-1], "wall"), "class_names lists 'wall' more than once"),
                         ((*CLASS_NAMES[:-1], "sky"), "'sky' is not a calnav class; valid: chair, bed")]:
        path = save_weights(net, tmp_path / "bad.pt", "learned_rgb", names, RES)
        for load in (lambda: check_weights(path, "learned_rgb"),
                     lambda: make_segmenter("learned_rgb", SegmenterConfig(weights=str(path)))):
            with pytest.raises(ValueError, match=f"segmenter weights {path}: {match}"):
                load()


def test_the_segmenters_own_device_wins_and_is_checked(weight_files):
    """``segmenter.device``, when set, is the device (the run's is the fallback), checked like
    ``run.device``: an error naming the key for a device that is not cpu / cuda."""
    seg = make_segmenter("learned_rgb", SegmenterConfig(weights=str(weight_files["learned_rgb"]), device="cpu"), "cuda")
    assert seg.device.type == "cpu"
    for name in SEGMENTER_NAMES:
        cfg = SegmenterConfig(weights=str(weight_files.get(name, "")), device="meta")
        with pytest.raises(ValueError, match="segmenter.device='meta' is not supported"):
            make_segmenter(name, cfg, "cpu")


def test_segmenter_config_errors_name_the_one_segmenter_section():
    """The segmenter's settings are the top-level ``segmenter`` section for every command: its
    range errors are prefixed with the section by the config loader, so they must not name a
    section of their own; the section's old place in ObjectNav configs
    (``agent.segmenter_config``) is read as it, with a note."""
    from calnav.eval.config import MAP_SECTIONS, ConfigError, load_config

    for overrides, kw in ((["segmenter.threads=-1"], {}), (["agent.segmenter_config.threads=-1"], {}),
                          (["segmenter.threads=-1"], {"sections": MAP_SECTIONS})):
        with pytest.raises(ConfigError, match=r"^segmenter: threads must be in \[0, 1024\] threads, got -1$"):
            load_config(None, overrides, **kw)
    with pytest.raises(ConfigError, match=r"^segmenter: gt_confidence must be in \(0, 1\], got 2.0$"):
        load_config(None, ["segmenter.gt_confidence=2"], sections=MAP_SECTIONS)


def test_default_weight_location_is_inside_the_package():
    assert default_weights_path("learned_rgb").parent.name == "weights"
    assert default_weights_path("learned_rgb").parent.parent.name == "agent"


@pytest.mark.parametrize("stem", ["learned_rgb", "learned_rgbd"])
def test_shipped_weights_match_their_cards_and_load(stem):
    """Every shipped weight file is the one its training card describes (sha256) and loads as
    the model the card names: the README tables cite these files by name."""
    path, card = WEIGHTS_DIR / f"{stem}.pt", json.loads((WEIGHTS_DIR / f"{stem}.json").read_text())
    assert hashlib.sha256(path.read_bytes()).hexdigest() == card["weights_sha256"]
    seg = make_segmenter(card["model"], SegmenterConfig(weights=str(path)))
    assert tuple(seg.class_names) == tuple(CLASS_NAMES)


# ------------------------------------------------------------------------------------- gt
@pytest.mark.parametrize("conf", [0.9, 0.5, 1.0])
def test_gt_confidence_is_exact(conf, frames):
    seg = make_segmenter("gt", SegmenterConfig(gt_confidence=conf))
    labels = frames.labels[0].astype(np.int64)
    p = softmax(seg(frames.rgb[0], None, semantic=labels).astype(np.float64))
    valid = labels >= 0
    assert valid.any()
    rows, cols = np.nonzero(valid)
    np.testing.assert_allclose(p[rows, cols, labels[valid]], conf, rtol=1e-6)
    if conf < 1:
        others = p[valid].sum(-1) - p[rows, cols, labels[valid]]
        np.testing.assert_allclose(others, 1 - conf, rtol=1e-5)
    void = labels.copy()
    void[:4] = -1
    np.testing.assert_allclose(softmax(seg(frames.rgb[0], None, semantic=void))[:4], 1 / K, rtol=1e-6)


# ---------------------------------------------------------------------------------- noisy
H, W = 48, 64


def _wall(depth_m, cls="wall"):
    """A fronto-parallel plane of one class at ``depth_m`` filling a 64x48 image."""
    return (np.zeros((H, W, 3), np.uint8), np.full((H, W), depth_m, np.float32),
            np.full((H, W), class_id(cls), np.int16))


def _strips(n=16, cls="chair"):
    """n vertical strips, each its own instance of ``cls``, on a plane 2 m away."""
    rgb, depth, sem = _wall(2.0, cls)
    inst = np.repeat(np.arange(n), W // n)[None, :].repeat(H, 0).astype(np.int32)
    return rgb, depth, sem, inst


def _instance_classes(logits, inst, n):
    pred = logits.argmax(-1)
    return np.array([np.bincount(pred[inst == i], minlength=K).argmax() for i in range(n)])


def test_noisy_is_deterministic_and_seeded(frames):
    kw = inputs(frames, 1)
    a = make_segmenter("noisy", SegmenterConfig(seed=1))(frames.rgb[1], frames.depth[1].astype(np.float32), **kw)
    b = make_segmenter("noisy", SegmenterConfig(seed=1))(frames.rgb[1], frames.depth[1].astype(np.float32), **kw)
    c = make_segmenter("noisy", SegmenterConfig(seed=2))(frames.rgb[1], frames.depth[1].astype(np.float32), **kw)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_noisy_instance_confusion_is_consistent_across_nearby_views():
    """Only instance confusions (no cell errors): every chair instance is confusable, over a
    120 degree azimuth arc. Nearby viewpoints agree instance by instance; a viewpoint looking
    the opposite way (azimuth + 180 > arc) never confuses an instance the first one confused."""
    cfg = SegmenterConfig(seed=5, instance_confusion_prob=1.0, confusion_arc_deg=120.0, base_error=0.0,
                          error_per_m=0.0, grazing_error=0.0)
    seg = make_segmenter("noisy", cfg)
    rgb, depth, sem, inst = _strips()
    n, chair, stool = 16, class_id("chair"), class_id("stool")
    confused = {}
    for yaw0 in np.deg2rad([0, 45, 90, 135]):
        views = {}
        for name, (dxy, dyaw) in {"a": ((0, 0), 0.0), "near": ((0.05, 0.03), 0.03),
                                  "opposite": ((0, 0), np.pi)}.items():
            pose = camera_pose(np.array(dxy), yaw0 + dyaw, 0.88)
            views[name] = _instance_classes(seg(rgb, depth, semantic=sem, instance=inst, pose=pose), inst, n)
        assert set(np.unique(views["a"])) <= {chair, stool}       # chair is only ever mistaken for stool
        np.testing.assert_array_equal(views["a"], views["near"])
        assert not ((views["a"] == stool) & (views["opposite"] == stool)).any()
        confused[yaw0] = views["a"] == stool
    rates = np.mean([v.mean() for v in confused.values()])
    assert 0.1 < rates < 0.7   # about arc / 360 = 1/3 of (instance, view) pairs are confused
    # a full arc: confusable instances are confused from everywhere
    full = make_segmenter("noisy", SegmenterConfig(**{**cfg.__dict__, "confusion_arc_deg": 360.0}))
    out = full(rgb, depth, semantic=sem, instance=inst, pose=camera_pose(np.zeros(2), 0.3, 0.88))
    assert (_instance_classes(out, inst, n) == stool).all()


def test_noisy_more_errors_far_than_near():
    """A wall (no instance confusions: walls are not confusable instances) seen head-on from
    1 m and from 4.5 m at several places: the far error rate is several times the near one."""
    seg = make_segmenter("noisy", SegmenterConfig(seed=0))
    rates = {}
    for d in (1.0, 4.5):
        rgb, depth, sem = _wall(d)
        errs = []
        for i in range(12):
            pose = camera_pose(np.array([0.37 * i, -0.91 * i]), 0.2 * i, 0.88)
            errs.append((seg(rgb, depth, semantic=sem, pose=pose).argmax(-1) != sem).mean())
        rates[d] = float(np.mean(errs))
    expected_far = 0.02 + 0.04 * 3.5
    assert rates[4.5] > 3 * rates[1.0]
    assert abs(rates[4.5] - expected_far) < 0.08


def test_noisy_grazing_views_are_worse():
    seg = make_segmenter("noisy")
    p = seg.error_probability(np.array([2.0, 2.0]), np.array([1.0, np.cos(np.deg2rad(80))]))
    assert p[1] > p[0]


def test_noisy_is_overconfident(frames):
    seg = make_segmenter("noisy")
    acc, conf = [], []
    for i in range(len(frames.rgb)):
        p = softmax(seg(frames.rgb[i], frames.depth[i].astype(np.float32), **inputs(frames, i)))
        valid = frames.labels[i] >= 0
        acc.append((p.argmax(-1)[valid] == frames.labels[i][valid]).mean())
        conf.append(p.max(-1)[valid].mean())
    assert np.mean(conf) > np.mean(acc)
    assert np.mean(acc) < 1.0


def test_noisy_without_instance_or_pose_still_works(frames):
    seg = make_segmenter("noisy")
    out = seg(frames.rgb[0], frames.depth[0].astype(np.float32), semantic=frames.labels[0])
    assert out.shape == (RES[1], RES[0], K) and np.isfinite(out).all()


def test_noisy_config_errors():
    with pytest.raises(ValueError, match="unknown class 'throne'"):
        make_segmenter("noisy", SegmenterConfig(confusions={"chair": ["throne"]}))
    with pytest.raises(ValueError, match="temperature"):
        SegmenterConfig(temperature=0)


def test_goal_and_structure_classes_exist():
    assert set(GOAL_CATEGORIES) | set(STRUCTURE_CLASSES) <= set(CLASS_NAMES)


# --------------------------------------------------------------------------------- layout
def test_agent_segmenters_do_not_import_envs():
    # the installed names (calnav.*): a segmenter plugin must load without the simulator
    code = ("import sys, calnav.agent.segmenters as s, calnav.agent.segmenters.learned, calnav.agent.segmenters.noisy, "
            "calnav.agent.segmenters.ground_truth; bad = [m for m in sys.modules if m.startswith('calnav.envs')]; "
            "assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_cuda_precision_follows_the_tf32_key():
    """On CUDA calnav forbids TensorFloat-32 unless asked (torch allows it for cuDNN convolutions
    by default: on an H200 learned_rgb's logits then differed from the CPU's by 1.1e-2, against
    9e-6 without); on the CPU nothing is touched."""
    import torch

    from calnav.agent.segmenters.base import set_cuda_precision

    saved = torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32
    try:
        torch.backends.cudnn.allow_tf32 = torch.backends.cuda.matmul.allow_tf32 = True
        set_cuda_precision(torch.device("cpu"), False)
        assert torch.backends.cudnn.allow_tf32
        set_cuda_precision(torch.device("cuda"), False)
        assert not torch.backends.cudnn.allow_tf32 and not torch.backends.cuda.matmul.allow_tf32
        set_cuda_precision(torch.device("cuda:1"), True)
        assert torch.backends.cudnn.allow_tf32 and torch.backends.cuda.matmul.allow_tf32
    finally:
        torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32 = saved


@pytest.mark.parametrize("key,value", [("temperature", float("nan")), ("error_cell_m", float("inf")),
                                       ("near_m", float("nan")), ("invalid_depth_m", -1.0), ("hfov_deg", 180.0),
                                       ("error_per_m", float("nan")), ("grazing_error", 1.5)])
def test_segmenter_keys_refuse_nan_inf_and_values_out_of_range(key, value):
    # "> 0" comparisons let NaN through: every numeric key has a declared range instead
    with pytest.raises(ValueError, match=rf"^{key} must be in "):
        SegmenterConfig(**{key: value})
