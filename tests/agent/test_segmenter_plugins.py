"""Bring your own segmenter: plugins by import path and by entry point, the ``hf`` and ``onnx``
adapters, each through an ObjectNav episode and ``calnav map``; bad plugins get one-line errors
before anything is written. No downloads: every model is built here."""
from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest

from calnav.agent.segmenters import SegmenterConfig, check_segmenter_spec, make_segmenter
from calnav.eval.cli import main
from tests.conftest import assert_same_records, read_records, small_or_full
from tests.sequence_data import write_scannet

PLUGINS = "tests.agent.segmenter_plugins"
SMALL = ["env.resolution=64x48", "env.dataset.val_scenes=1", "env.dataset.episodes_per_scene=2",
         "env.max_episode_steps=60", "run.workers=1"]


def _objectnav(out, *overrides, episodes="0:2") -> int:
    return main(["objectnav", "--episodes", episodes, "--output", str(out), *SMALL, *overrides])


def _map(seq, out, segmenter, *overrides) -> int:
    return main(["map", str(seq), "--layout", "scannet", "--segmenter", segmenter, "--output", str(out), *overrides])


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    return write_scannet(tmp_path_factory.mktemp("seq") / "scene0000_00", n=4)


@pytest.fixture(scope="module")
def builtin_records(tmp_path_factory):
    """{episode index: record} of a built-in segmenter's episodes 0:2 (SMALL), run once for the
    module: the reference the plugins' episodes are compared with (records are deterministic)."""
    runs: dict[str, dict] = {}

    def records(segmenter: str) -> dict:
        if segmenter not in runs:
            out = tmp_path_factory.mktemp(f"builtin_{segmenter}")
            assert _objectnav(out, f"agent.segmenter={segmenter}") == 0
            runs[segmenter] = read_records(out)
        return runs[segmenter]
    return records


@pytest.fixture(scope="module")
def hf_dir(tmp_path_factory):
    """A tiny random-initialised Segformer over ADE20K's 150 classes, saved with save_pretrained
    beside its image processor (what a user's fine-tuned checkpoint directory holds)."""
    from transformers import SegformerConfig, SegformerForSemanticSegmentation, SegformerImageProcessor
    from transformers.utils import logging as hf_logging

    from calnav.agent.segmenters.label_map import read_label_map

    names = read_label_map("ade20k").model_classes
    cfg = SegformerConfig(num_encoder_blocks=2, depths=[1, 1], sr_ratios=[2, 1], hidden_sizes=[8, 16],
                          patch_sizes=[7, 3], strides=[4, 2], num_attention_heads=[1, 1], mlp_ratios=[2, 2],
                          decoder_hidden_size=16, num_labels=len(names), id2label=dict(enumerate(names)),
                          label2id={n: i for i, n in enumerate(names)})
    out = tmp_path_factory.mktemp("segformer")
    hf_logging.disable_progress_bar()
    SegformerForSemanticSegmentation(cfg).save_pretrained(out)
    SegformerImageProcessor(size={"height": 96, "width": 128}).save_pretrained(out)
    return out


@pytest.fixture(scope="module")
def onnx_file(tmp_path_factory):
    from calnav.eval.segmenter.export_onnx import export

    path = tmp_path_factory.mktemp("onnx") / "learned_rgb.onnx"
    export("learned_rgb", "", path)
    return path


# ------------------------------------------------------------------------------ import path
def test_import_path_plugin_gives_the_builtins_logits_and_episodes(tmp_path, builtin_records):
    frame = np.random.default_rng(0).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    depth = np.full((48, 64), 2.0, np.float32)
    plugin = make_segmenter(f"{PLUGINS}:wrapped_learned_rgbd")
    np.testing.assert_array_equal(plugin(frame, depth), make_segmenter("learned_rgbd")(frame, depth))
    assert _objectnav(tmp_path / "plugin", f"agent.segmenter={PLUGINS}:wrapped_learned_rgbd") == 0
    a, b = read_records(tmp_path / "plugin"), builtin_records("learned_rgbd")
    assert len(a) == 2 and all(r["status"] == "ok" for r in a.values())
    assert_same_records(a, b, tol=1e-9)


@pytest.mark.parametrize("spec,message", [
    ("tests.agent.no_such_module:make", "cannot be loaded: ModuleNotFoundError: No module named 'tests.agent.no_such_module'"),
    (f"{PLUGINS}:no_such_factory", "cannot be loaded: AttributeError"),
    (f"{PLUGINS}:NOT_CALLABLE", "is a int, not a factory function"),
    (f"{PLUGINS}:raising", "its factory raised RuntimeError: no GPU memory left"),
    (f"{PLUGINS}:not_a_segmenter", "returned object without class_names, segment"),
    (f"{PLUGINS}:wrong_k", r"returned logits of shape \(48, 64, 17\) for a 48x64 frame; expected \(H, W, K\) = \(48, 64, 18\)"),
    (f"{PLUGINS}:wrong_shape", r"returned logits of shape \(24, 64, 18\)"),
    (f"{PLUGINS}:nan_logits", "returned non-finite logits"),
    (f"{PLUGINS}:no_tv", "predicts no tv_monitor"),
    (f"{PLUGINS}:nyu40_constant", "predicts no plant .*label map nyu40: map a model class to each"),
    # class lists that cannot be matched to calnav's classes by name
    (f"{PLUGINS}:duplicate_classes", "class_names lists 'wall' more than once; every output channel needs its own "
                                     "class; valid: chair, bed"),
    (f"{PLUGINS}:unknown_classes", "'sky', 'person' are not calnav classes; valid: chair, bed, .*; map the model's "
                                   "classes with segmenter.label_map"),
    (f"{PLUGINS}:string_classes", "class_names must be a list of class names, got the string 'chair'"),
    ("segformer", "unknown segmenter 'segformer'; valid: gt, noisy, learned_rgb, learned_rgbd, hf, onnx"),
])
def test_bad_plugins_fail_in_one_line_before_anything_is_written(tmp_path, capsys, spec, message):
    out = tmp_path / "out"
    overrides = [f"agent.segmenter={spec}"] + (["segmenter.label_map=nyu40"] if "nyu40" in spec else [])
    assert _objectnav(out, *overrides) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert re.search(message, err), err
    assert not out.exists()


def test_a_plugin_in_another_class_order_gives_the_same_episodes(tmp_path, builtin_records):
    """learned_rgb behind a plugin that lists its classes and channels in reverse: matched to
    calnav's classes by name, its logits, goal channels and episodes are learned_rgb's (the goal's
    channel used to be looked up by the task's category id in the plugin's list)."""
    plugin, builtin = make_segmenter(f"{PLUGINS}:reversed_learned_rgb"), make_segmenter("learned_rgb")
    assert plugin.class_names == builtin.class_names
    frame = np.random.default_rng(4).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    np.testing.assert_array_equal(plugin(frame), builtin(frame))
    assert _objectnav(tmp_path / "plugin", f"agent.segmenter={PLUGINS}:reversed_learned_rgb") == 0
    a, b = read_records(tmp_path / "plugin"), builtin_records("learned_rgb")
    assert len(a) == 2 and all(r["status"] == "ok" for r in a.values())
    assert_same_records(a, b, tol=1e-9)


def test_a_plugin_cannot_change_the_frame_it_segments():
    """A plugin that writes into its rgb and depth (in-place preprocessing) gets copies: the
    caller's frame -- the agent's depth, which the map fuses next -- stays as it was."""
    rgb = np.random.default_rng(5).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    depth = np.linspace(0.5, 4.0, 48 * 64, dtype=np.float32).reshape(48, 64)
    rgb0, depth0 = rgb.copy(), depth.copy()
    out = make_segmenter(f"{PLUGINS}:mutating_learned_rgbd")(rgb, depth)
    np.testing.assert_array_equal(rgb, rgb0)
    np.testing.assert_array_equal(depth, depth0)
    np.testing.assert_array_equal(out, make_segmenter("learned_rgbd")(rgb0, depth0))


@pytest.mark.parametrize("device,message", [
    ("tpu", "segmenter.device='tpu' is not a torch device"),
    ("meta", "segmenter.device='meta' is not supported; use 'cpu', 'cuda' or 'cuda:N'"),
    ("cuda:99", "segmenter.device='cuda:99' requested but (CUDA is not available|only [0-9]+ CUDA)"),
])
def test_the_segmenters_own_device_is_checked_before_anything_is_written(tmp_path, capsys, device, message):
    out = tmp_path / "out"
    assert _objectnav(out, "agent.segmenter=learned_rgb", f"segmenter.device={device}") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and re.search(message, err), err
    assert not out.exists()


def test_the_calibration_study_needs_every_calnav_class(tmp_path, capsys):
    """Its maps are scored against labels of every calnav class: a plugin that predicts fewer is
    refused before the study writes anything (it used to fail once a house was scanned)."""
    out = tmp_path / "study"
    assert main(["calibrate-map", "--output", str(out), f"study.segmenters=[{PLUGINS}:no_bed]"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"study.segmenters: segmenter {PLUGINS}:no_bed predicts no bed" in err, err
    assert not out.exists()


def test_a_label_mapped_plugin_maps_in_calnav_classes(sequence, tmp_path):
    """A model over NYU40 that says 'chair' everywhere, through the nyu40 map: calnav's 18
    classes, chair on top with its probability, no goal check outside ObjectNav."""
    cfg = SegmenterConfig(label_map="nyu40")
    seg = make_segmenter(f"{PLUGINS}:nyu40_constant", cfg)
    p = np.exp(seg(np.zeros((4, 5, 3), np.uint8)))
    from calnav.agent.segmenters.base import default_class_names

    names = default_class_names()
    assert seg.class_names == names and "plant" not in seg.predicted_classes
    from calnav.agent.segmenters.label_map import read_label_map

    targets = read_label_map("nyu40").targets
    assert targets.count("chair") == 1 and targets.count(None) == 20
    q = 1.0 / (np.exp(3.0) + 39)   # every other NYU40 class; chair has e^3 q
    np.testing.assert_allclose(p[..., names.index("chair")], np.exp(3.0) * q + 20 * q / 18, rtol=1e-5)
    np.testing.assert_allclose(p[..., names.index("plant")], 20 * q / 18, rtol=1e-5)   # rest share only
    assert _map(sequence, tmp_path / "m", f"{PLUGINS}:nyu40_constant", "segmenter.label_map=nyu40") == 0
    from calnav.common.npz import load_versioned_npz
    from calnav.eval.sequence.map_cmd import MAP_FORMAT_VERSION

    arrays, meta = load_versioned_npz(tmp_path / "m" / "map.npz", MAP_FORMAT_VERSION)
    assert tuple(meta["class_names"]) == names and (arrays["probs"].argmax(1) == names.index("chair")).all()


# ------------------------------------------------------------------------------ entry point
def test_entry_point_plugin_from_an_installed_distribution(tmp_path, monkeypatch, sequence, capsys, builtin_records):
    src = tmp_path / "src"
    src.mkdir()
    (src / "pyproject.toml").write_text(
        '[build-system]\nrequires = ["setuptools>=64"]\nbuild-backend = "setuptools.build_meta"\n\n'
        '[project]\nname = "calnav-test-plugin"\nversion = "0.1"\n\n'
        '[project.entry-points."calnav.segmenters"]\ncalnav-test-seg = "calnav_test_plugin:make"\n')
    (src / "calnav_test_plugin.py").write_text(
        "from calnav.agent.segmenters import make_segmenter\n\n\n"
        "def make(cfg, device):\n    return make_segmenter('learned_rgb', cfg, device)\n")
    site = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
                    "--target", str(site), str(src)], check=True, capture_output=True)
    with pytest.raises(ValueError, match="unknown segmenter 'calnav-test-seg'"):
        check_segmenter_spec("calnav-test-seg")
    monkeypatch.syspath_prepend(str(site))
    assert check_segmenter_spec("calnav-test-seg") == "calnav-test-seg"
    with pytest.raises(ValueError, match="installed plugins: calnav-test-seg"):
        check_segmenter_spec("calnav-test-sge")
    assert _objectnav(tmp_path / "run", "agent.segmenter=calnav-test-seg", episodes="0:1") == 0
    run = read_records(tmp_path / "run")
    assert list(run) == [0]
    assert_same_records(run, {0: builtin_records("learned_rgb")[0]}, tol=1e-9)   # episode 0 of the reference
    assert _map(sequence, tmp_path / "map", "calnav-test-seg") == 0


# ------------------------------------------------------------------------------ hf
def test_hf_segformer_with_the_ade20k_map(hf_dir, sequence, tmp_path):
    """Logits equal the model's own ADE20K probabilities summed per calnav class (the rest spread
    evenly) and upsampled as the processor's post-processing does; then an episode and a map."""
    import torch
    import torch.nn.functional as F
    from transformers import AutoImageProcessor, AutoModelForSemanticSegmentation

    from calnav.agent.segmenters.base import default_class_names
    from calnav.agent.segmenters.label_map import mapping_matrix, read_label_map

    seg = make_segmenter("hf", SegmenterConfig(model=str(hf_dir), label_map="ade20k"))
    rgb = np.random.default_rng(1).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    out = seg(rgb)
    assert out.shape == (48, 64, 18) and out.dtype == np.float32 and np.isfinite(out).all()
    model = AutoModelForSemanticSegmentation.from_pretrained(hf_dir).eval()
    with torch.no_grad():
        z = model(**AutoImageProcessor.from_pretrained(hf_dir)(images=[rgb], return_tensors="pt")).logits
    a = torch.from_numpy(mapping_matrix(read_label_map("ade20k"), default_class_names()))
    p = (torch.softmax(z, 1).permute(0, 2, 3, 1) @ a).permute(0, 3, 1, 2)
    expect = F.interpolate(p, size=(48, 64), mode="bilinear", align_corners=False)[0].permute(1, 2, 0).numpy()
    np.testing.assert_allclose(np.exp(out), expect, rtol=1e-4, atol=1e-7)
    np.testing.assert_allclose(np.exp(out).sum(-1), 1.0, rtol=1e-4)
    hf = ["agent.segmenter=hf", f"segmenter.model={hf_dir}", "segmenter.label_map=ade20k"]
    assert _objectnav(tmp_path / "run", *hf, episodes="0:1") == 0
    assert read_records(tmp_path / "run")[0]["status"] == "ok"
    assert _map(sequence, tmp_path / "map", "hf", f"segmenter.model={hf_dir}", "segmenter.label_map=ade20k") == 0


def test_hf_errors(hf_dir, tmp_path, capsys):
    for overrides, message in [
        # the keys of the segmenter section, whichever command runs it
        (["segmenter.model=/nonexistent/segformer"],
         "segmenter.model /nonexistent/segformer does not exist"),
        ([f"segmenter.model={tmp_path}"], "segmenter.model .* has no config.json"),
        # ADE20K's classes without a label map: matched to calnav's by name, most are not calnav's
        ([f"segmenter.model={hf_dir}"], "segmenter hf: 'building', 'sky', .* are not calnav classes; "
                                                     "valid: chair, .*with segmenter.label_map"),
        ([f"segmenter.model={hf_dir}", "segmenter.label_map=scannet20"],
         "label map .*scannet20.tsv does not list the model's classes 'building'"),
    ]:
        assert _objectnav(tmp_path / "out", "agent.segmenter=hf", *overrides) == 2

        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and re.search(message, err), err
        assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------------------ onnx
def test_onnx_export_equals_torch(onnx_file, sequence, tmp_path, builtin_records):
    from calnav.agent.segmenters.learned import LearnedSegmenter

    onnx_seg = make_segmenter("onnx", SegmenterConfig(model=str(onnx_file)))
    torch_seg = LearnedSegmenter("learned_rgb", SegmenterConfig())
    assert onnx_seg.class_names == torch_seg.class_names and not onnx_seg.needs_depth
    rng = np.random.default_rng(2)
    for h, w in ((120, 160), (48, 64), (240, 320)):
        rgb = rng.integers(0, 256, (2, h, w, 3), dtype=np.uint8)
        diff = np.abs(onnx_seg.segment_batch(rgb) - torch_seg.segment_batch(rgb)).max()
        assert diff < 1e-4, (h, w, diff)
    assert _objectnav(tmp_path / "onnx", "agent.segmenter=onnx", f"segmenter.model={onnx_file}") == 0
    onnx = read_records(tmp_path / "onnx")
    assert len(onnx) == 2
    assert_same_records(onnx, builtin_records("learned_rgb"), tol=1e-9)
    assert _map(sequence, tmp_path / "map", "onnx", f"segmenter.model={onnx_file}") == 0


def test_export_onnx_cli(tmp_path, capsys):
    out = tmp_path / "rgbd.onnx"
    assert main(["export-onnx", "--segmenter", "learned_rgbd", "--output", str(out)]) == 0
    assert "logits equal to torch within" in capsys.readouterr().out
    seg = make_segmenter("onnx", SegmenterConfig(model=str(out)))
    assert seg.needs_depth and seg.num_classes == 18
    with pytest.raises(ValueError, match="needs depth"):
        seg(np.zeros((48, 64, 3), np.uint8))
    assert main(["export-onnx", "--segmenter", "learned_rgb", "--output", str(tmp_path)]) == 2
    assert "is a directory" in capsys.readouterr().err
    (tmp_path / "bad.onnx").write_bytes(b"not a model")
    with pytest.raises(ValueError, match="cannot load ONNX model"):
        make_segmenter("onnx", SegmenterConfig(model=str(tmp_path / "bad.onnx")))


# ------------------------------------------------------------------- GLFS and thresholds
def test_fit_glfs_and_tune_for_a_plugged_in_segmenter(onnx_file, sequence, tmp_path, capsys):
    """The whole path for a new model: fit GLFS to its observations, fuse a recording with those
    parameters, tune the goal threshold with it."""
    import json

    glfs = tmp_path / "glfs_onnx.json"
    tiny = ["study.calib_train_scenes=1", "study.calib_val_scenes=1", "scan.frames=40", "study.glfs_max_voxels=5000",
            "glfs.epochs=2", f"segmenter.model={onnx_file}", small_or_full("run.workers=1", "run.workers=0")]
    assert main(["fit-glfs", "--segmenter", "onnx", "--output", str(glfs), "--work-dir", str(tmp_path / "w"), *tiny]) == 0
    assert len(json.loads(glfs.read_text())["tau"]) == 18
    assert _map(sequence, tmp_path / "map", "onnx", f"segmenter.model={onnx_file}", "mapping.fusion=glfs",
                f"mapping.glfs_params={glfs}") == 0
    out = tmp_path / "tune"
    assert main(["tune", "--episodes", "0:1", "--thresholds", "0.9,0.6", "--min-areas", "3", "--output", str(out),
                 *SMALL, "agent.segmenter=onnx", f"segmenter.model={onnx_file}",
                 "mapping.fusion=glfs", f"mapping.glfs_params={glfs}"]) == 0
    from calnav.eval.config import load_config

    best = load_config(out / "best.yaml")   # a complete config for the evaluation run, the model included
    assert (out / "tune.csv").is_file() and best.agent.segmenter == "onnx" and best.agent.goal_threshold in (0.9, 0.6)
    assert best.segmenter.model == str(onnx_file) and best.mapping.glfs_params == str(glfs)
