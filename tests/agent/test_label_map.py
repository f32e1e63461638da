"""agent.segmenters.label_map: the built-in maps, user files, the combining rule (probabilities
added, rest bucket spread evenly) against hand-computed cases and as a property."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from calnav.agent.segmenters.adapter import ModelAdapter
from calnav.agent.segmenters.base import SegmenterConfig, default_class_names, goal_categories
from calnav.agent.segmenters.label_map import (BUILTIN_LABEL_MAPS, PROB_FLOOR, LabelMap, mapping_matrix,
                                               read_label_map)

CALNAV = default_class_names()


class FixedLogits(ModelAdapter):
    """An adapter whose model returns the given (B, K_m, h, w) logits."""

    def __init__(self, z, cfg, model_classes=None):
        self.z = torch.as_tensor(z, dtype=torch.float32)
        super().__init__("fixed", cfg, "cpu", model_classes, k_model=self.z.shape[1])

    def model_logits(self, rgb, depth):
        return self.z


def _probs(adapter, h, w):
    out = adapter.segment(np.zeros((h, w, 3), np.uint8))
    return np.exp(out)   # logits are log-probabilities


def test_hand_computed_many_to_one_and_rest(tmp_path):
    """Model classes (couch, sofa bed, sky): probabilities 0.25 / 0.5 / 0.25 (logits ln 1, ln 2,
    ln 1). couch and sofa bed -> sofa: 0.75 (added probabilities; adding logits would give a
    product); sky -> rest: 0.25 / 18 to every calnav class. So sofa = 0.75 + 0.25 / 18."""
    path = tmp_path / "m.yaml"
    path.write_text("couch: sofa\nsofa bed: sofa\nsky: null\n")
    z = np.log(np.array([1.0, 2.0, 1.0]))[None, :, None, None] * np.ones((1, 3, 2, 2))
    p = _probs(FixedLogits(z, SegmenterConfig(label_map=str(path)), ("couch", "sofa bed", "sky")), 2, 2)
    sofa = CALNAV.index("sofa")
    assert p.shape == (2, 2, len(CALNAV))
    np.testing.assert_allclose(p[..., sofa], 0.75 + 0.25 / 18, rtol=1e-5)
    others = np.delete(p, sofa, axis=-1)
    np.testing.assert_allclose(others, 0.25 / 18, rtol=1e-4)
    np.testing.assert_allclose(p.sum(-1), 1.0, rtol=1e-5)


def test_unmapped_calnav_class_gets_a_finite_floor():
    lm = LabelMap("t", ("a", "b"), ("chair", "bed"))
    a = mapping_matrix(lm, CALNAV)
    p = torch.softmax(torch.tensor([[0.0, 1.0]]), 1) @ torch.from_numpy(a)
    logits = torch.log(p.clamp_min(PROB_FLOOR))
    assert torch.isfinite(logits).all() and logits[0, CALNAV.index("plant")] == pytest.approx(np.log(PROB_FLOOR))


@settings(max_examples=40, deadline=None)
@given(st.integers(2, 12), st.integers(0, 2**31 - 1))
def test_mapped_probabilities_are_the_matrix_product(k_model, seed):
    """For any logits and any many-to-one map with a rest bucket: exp(calnav logits) =
    softmax(model logits) @ A, each pixel sums to 1, and a calnav class gets at least the
    probability of the model classes mapped to it."""
    rng = np.random.default_rng(seed)
    targets = tuple(None if rng.random() < 0.3 else CALNAV[int(rng.integers(len(CALNAV)))] for _ in range(k_model))
    names = tuple(f"m{i}" for i in range(k_model))
    z = rng.normal(0, 4, (2, k_model, 3, 4)).astype(np.float32)
    lm = LabelMap("t", names, targets)
    adapter = FixedLogits(z, SegmenterConfig(), CALNAV[:k_model])   # names of no account: the matrix is set below
    adapter.matrix = torch.from_numpy(mapping_matrix(lm, CALNAV))
    out = adapter.segment_batch(np.zeros((2, 3, 4, 3), np.uint8))
    pm = torch.softmax(torch.from_numpy(z), 1).permute(0, 2, 3, 1).numpy()
    expect = pm @ mapping_matrix(lm, CALNAV)
    np.testing.assert_allclose(np.exp(out), np.maximum(expect, PROB_FLOOR), rtol=1e-4, atol=1e-7)
    np.testing.assert_allclose(expect.sum(-1), 1.0, rtol=1e-5)
    for m, t in enumerate(targets):
        if t is not None:
            assert (expect[..., CALNAV.index(t)] >= pm[..., m] - 1e-6).all()


@pytest.mark.parametrize("name,size,missing_goals", [("ade20k", 150, []), ("coco_panoptic", 133, []),
                                                      ("nyu40", 40, ["plant"]), ("scannet20", 20, ["plant", "tv_monitor"])])
def test_builtin_maps(name, size, missing_goals):
    lm = read_label_map(name)
    assert name in BUILTIN_LABEL_MAPS and len(lm.model_classes) == size
    assert {t for t in lm.targets if t} <= set(CALNAV)
    if missing_goals:
        with pytest.raises(ValueError, match="no model class maps to goal categor.* " + ", ".join(missing_goals) + ";"):
            mapping_matrix(lm, CALNAV, goal_categories())
    else:
        mapping_matrix(lm, CALNAV, goal_categories())


def test_ade20k_map_spot_checks():
    lm = dict(zip(*(read_label_map("ade20k").model_classes, read_label_map("ade20k").targets)))
    assert lm["armchair"] == lm["swivel chair"] == lm["chair"] == "chair"
    assert lm["television receiver"] == lm["crt screen"] == lm["monitor"] == "tv_monitor"
    assert lm["bed"] == "bed" and lm["sky"] is None and lm["person"] is None and lm["screen door"] == "door"


def test_user_files_in_three_formats_agree(tmp_path):
    rows = [("chair", "chair"), ("couch", "sofa"), ("sky", None)]
    (tmp_path / "m.tsv").write_text("# mine\nid\tmodel_class\tcalnav_class\n"
                                    + "".join(f"{i}\t{a}\t{b or ''}\n" for i, (a, b) in enumerate(rows)))
    (tmp_path / "m.yaml").write_text("".join(f"{a}: {b or 'null'}\n" for a, b in rows))
    (tmp_path / "m.json").write_text(json.dumps({a: b for a, b in rows}))
    maps = [read_label_map(str(tmp_path / f"m.{ext}")) for ext in ("tsv", "yaml", "json")]
    assert {(m.model_classes, m.targets) for m in maps} == {(("chair", "couch", "sky"), ("chair", "sofa", None))}


@pytest.mark.parametrize("text,suffix,match", [
    ("model\tcalnav\n0\ta\tchair\n", ".tsv", "header"),
    ("id\tmodel_class\tcalnav_class\n1\ta\tchair\n", ".tsv", "row 1 must be '0"),
    ("id\tmodel_class\tcalnav_class\n0\ta\tchair\n1\ta\tbed\n", ".tsv", "model class 'a' is listed twice"),
    # YAML and JSON parsers keep the last of two equal keys: a model's wall would become ceiling
    ("wall: wall\nfloor: floor\nwall: ceiling\n", ".yaml", r"model class 'wall' is listed twice \(lines 1 and 3\)"),
    ("{wall: wall, wall: ceiling}\n", ".yaml", "model class 'wall' is listed twice"),
    ('{"wall": "wall", "floor": "floor", "wall": "ceiling"}', ".json", "model class 'wall' is listed twice"),
    ("- a\n- b\n", ".yaml", "must be a mapping"),
    ("{bad json", ".json", "cannot read label map"),
    ("a: chair\n", ".csv", "unknown format '.csv'"),
])
def test_bad_label_map_files(tmp_path, text, suffix, match):
    path = tmp_path / f"m{suffix}"
    path.write_text(text)
    with pytest.raises(ValueError, match=match):
        read_label_map(str(path))


def test_unknown_map_and_unknown_target(tmp_path):
    with pytest.raises(FileNotFoundError, match="neither a built-in map .*ade20k, nyu40, scannet20, coco_panoptic"):
        read_label_map("ade21k")
    with pytest.raises(ValueError, match="armchair not calnav classes; valid: chair, bed"):
        mapping_matrix(LabelMap("t", ("a",), ("armchair",)), CALNAV)


def test_model_classes_are_matched_by_name_or_by_order(tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text("sky: null\ncouch: sofa\n")
    z = np.zeros((1, 2, 1, 1), np.float32)
    z[0, 1] = 5.0   # channel 1
    by_name = _probs(FixedLogits(z, SegmenterConfig(label_map=str(path)), ("couch", "sky")), 1, 1)
    assert by_name[..., CALNAV.index("sofa")] < 0.1          # channel 1 is sky for this model: spread evenly
    by_order = _probs(FixedLogits(z, SegmenterConfig(label_map=str(path)), ("LABEL_0", "LABEL_1")), 1, 1)
    assert by_order[..., CALNAV.index("sofa")] > 0.9          # placeholder names: the map's order
    with pytest.raises(ValueError, match="does not list the model's classes 'tree'"):
        FixedLogits(z, SegmenterConfig(label_map=str(path)), ("couch", "tree"))
    with pytest.raises(ValueError, match="the model predicts 3 classes, label map .* lists 2"):
        FixedLogits(np.zeros((1, 3, 1, 1)), SegmenterConfig(label_map=str(path)))


def test_model_class_names_are_compared_stripped(tmp_path):
    """Segformer's ADE20K checkpoints spell class 7 "bed " (trailing space): it is the map's bed."""
    path = tmp_path / "m.yaml"
    path.write_text("bed: bed\nsky: null\n")
    z = np.zeros((1, 2, 1, 1), np.float32)
    z[0, 0] = 5.0
    p = _probs(FixedLogits(z, SegmenterConfig(label_map=str(path)), ("bed ", "sky")), 1, 1)
    assert p[..., CALNAV.index("bed")] > 0.9


# ------------------------------------------------------------ a model's own classes, by name
def test_model_classes_without_a_map_are_matched_to_calnav_by_name():
    """A model that predicts calnav's classes in another order: its channels are put in calnav's
    order by name, so its logits are those of the same model in calnav's order."""
    rng = np.random.default_rng(3)
    z = rng.normal(0, 2, (1, len(CALNAV), 3, 4)).astype(np.float32)
    in_order = FixedLogits(z, SegmenterConfig(), CALNAV)
    backwards = FixedLogits(z[:, ::-1].copy(), SegmenterConfig(), CALNAV[::-1])
    assert in_order.class_names == backwards.class_names == CALNAV
    np.testing.assert_array_equal(backwards.segment(np.zeros((3, 4, 3), np.uint8)),
                                  in_order.segment(np.zeros((3, 4, 3), np.uint8)))
    some = ("wall", "chair", "floor")   # a model of some calnav classes keeps them, in calnav's order
    part = FixedLogits(z[:, :3], SegmenterConfig(), some)
    assert part.class_names == ("chair", "floor", "wall") and part.channels == (1, 2, 0)


@pytest.mark.parametrize("names,match", [
    ((*CALNAV[:-1], "wall"), "class_names lists 'wall' more than once; every output channel needs its own class; "
                             "valid: chair, bed"),
    ((*CALNAV, "sky", "person"), "'sky', 'person' are not calnav classes; valid: chair, bed, .*; map the model's "
                                 r"classes with segmenter.label_map \(ade20k"),
    ("chair", "class_names must be a list of class names, got the string 'chair'"),
    ((*CALNAV[:-1], 7), "class_names must be strings, got 7"),
])
def test_model_class_lists_that_cannot_be_matched_are_refused(names, match):
    with pytest.raises(ValueError, match=match):
        FixedLogits(np.zeros((1, len(names), 1, 1)), SegmenterConfig(), names)
