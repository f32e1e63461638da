"""Sample weighting (mapping.weighting), logit scaling and GLFS parameters (mapping.glfs)."""
import numpy as np
import pytest
import torch

from calnav.mapping.config import MappingConfig
from calnav.mapping.glfs import GLFSParams
from calnav.mapping.registry import WEIGHTINGS, weighting_choices
from calnav.mapping.scaling import as_temperature
from calnav.mapping.weighting import (ANGLE_EDGES_DEG, DISTANCE_EDGES_M, WeightingParams, bin_index, resolve,
                                      sample_weights)

K = 4
CHOICES = "auto, none, lut, distance, incidence, sweet_spot"


def test_every_registered_weighting_loads_and_weighs():
    """Each lazy reference of ``WEIGHTINGS`` resolves to a weight function: one finite weight in
    (0, 1] per observation (a reference to a missing function fails here)."""
    params = WeightingParams(lut=torch.ones(K, len(DISTANCE_EDGES_M) - 1, len(ANGLE_EDGES_DEG) - 1))
    pred, d, a = torch.tensor([0, 3]), torch.tensor([0.5, 4.0]), torch.tensor([10.0, 80.0])
    for name in WEIGHTINGS:
        w = sample_weights(name, pred, d, a, params)
        assert w.shape == (2,) and bool(((w > 0) & (w <= 1)).all()), name
    assert weighting_choices() == ("auto", *WEIGHTINGS.names())


def test_auto_resolves_and_unknown_names_list_the_choices():
    assert resolve("auto", "glfs") == "lut" and resolve("auto", "rbu") == "none"
    assert resolve("incidence", "glfs") == "incidence"
    one_line = f"^unknown sample weighting 'gaussian' for mapping.weighting; valid choices: {CHOICES}$"
    with pytest.raises(ValueError, match=one_line):
        resolve("gaussian", "rbu")
    with pytest.raises(ValueError, match=one_line):
        MappingConfig(weighting="gaussian")
    with pytest.raises(ValueError, match="valid choices: none, lut"):   # "auto" is no weight function
        sample_weights("auto", torch.zeros(1, dtype=torch.long), torch.ones(1), torch.ones(1))
    with pytest.raises(ValueError, match="^unknown fusion strategy 'bayes' for mapping.fusion; valid choices: rbu"):
        MappingConfig(fusion="bayes")


def test_lut_bins_follow_the_authors_edges():
    d = torch.tensor([0.0, 0.99, 1.0, 4.5, 5.0, 12.0])
    a = torch.tensor([0.0, 29.9, 30.0, 59.0, 60.0, 95.0])
    assert bin_index(d, (0, 1, 2, 3, 4, 5)).tolist() == [0, 0, 1, 4, 4, 4]  # beyond the last edge -> last bin
    assert bin_index(a, (0, 30, 60, 90)).tolist() == [0, 0, 1, 1, 2, 2]
    m = torch.arange(K * 5 * 3, dtype=torch.float32).reshape(K, 5, 3) - 3.0  # a few negative entries
    pred = torch.tensor([0, 0, 1, 3, 3, 2])
    w = sample_weights("lut", pred, d, a, WeightingParams(lut=m))
    expected = m.clamp_min(0)[pred, bin_index(d, (0, 1, 2, 3, 4, 5)), bin_index(a, (0, 30, 60, 90))]
    assert torch.equal(w, expected)
    assert w[0] == 0.0  # M clipped >= 0
    with pytest.raises(ValueError, match="look-up table"):
        sample_weights("lut", pred, d, a, WeightingParams())


def test_lut_is_differentiable_wrt_the_table():
    m = torch.ones(K, 5, 3, requires_grad=True)
    w = sample_weights("lut", torch.tensor([1, 2]), torch.tensor([0.5, 3.2]), torch.tensor([10.0, 70.0]), WeightingParams(lut=m))
    w.sum().backward()
    assert m.grad[1, 0, 0] == 1 and m.grad[2, 3, 2] == 1 and m.grad.sum() == 2


def test_analytic_heuristics():
    p = WeightingParams(distance_ref_m=1.0, sweet_spot_m=1.5, sweet_spot_halfwidth_m=3.0, min_weight=0.05)
    pred = torch.zeros(5, dtype=torch.long)
    d = torch.tensor([0.5, 1.0, 2.0, 4.0, 50.0])
    a = torch.tensor([0.0, 30.0, 60.0, 89.0, 90.0])
    assert torch.allclose(sample_weights("none", pred, d, a, p), torch.ones(5))
    assert torch.allclose(sample_weights("distance", pred, d, a, p), torch.tensor([1.0, 1.0, 0.25, 0.0625, 0.05]))
    inc = sample_weights("incidence", pred, d, a, p)
    assert torch.allclose(inc[:3], torch.cos(torch.deg2rad(a[:3])), atol=1e-6) and inc[4] == pytest.approx(0.05)
    sweet = sample_weights("sweet_spot", pred, torch.tensor([1.5, 0.0, 3.0, 4.5, 10.0]), a, p)
    assert torch.allclose(sweet, torch.tensor([1.0, 0.75, 0.75, 0.05, 0.05]))


def test_temperature_validation():
    assert as_temperature(2.0, K).shape == ()
    assert as_temperature(np.ones(K), K).shape == (K,)
    with pytest.raises(ValueError, match="per class"):
        as_temperature(np.ones(K + 1), K)
    with pytest.raises(ValueError, match="> 0"):
        as_temperature(-1.0, K)
    with pytest.raises(ValueError, match="> 0"):
        as_temperature(float("nan"), K)


def test_glfs_params_roundtrip_and_class_check(tmp_path):
    names = ("chair", "bed", "wall", "floor")
    rng = np.random.default_rng(0)
    p = GLFSParams(tau=rng.uniform(0.5, 2, K), g=0.3, eps=0.7, M=rng.uniform(0, 2, (K, 5, 3)), class_names=names)
    for suffix in (".json", ".npz"):
        q = GLFSParams.load(p.save(tmp_path / f"glfs{suffix}"))
        assert np.array_equal(q.tau, p.tau) and np.array_equal(q.M, p.M)
        assert (q.g, q.eps, q.class_names, q.distance_edges, q.angle_edges_deg) == \
            (p.g, p.eps, p.class_names, p.distance_edges, p.angle_edges_deg)
    p.check_classes(names)
    with pytest.raises(ValueError, match="other classes"):
        p.check_classes(("chair", "bed", "floor", "wall"))
    with pytest.raises(ValueError, match="for 4 classes, the map has 3"):
        p.check_classes(names[:3])
    identity = GLFSParams.identity(K)
    assert identity.M.shape == (K, 5, 3) and (identity.M == 1).all() and (identity.tau == 1).all()
    assert (identity.g, identity.eps) == (0.0, 0.0)


def test_glfs_params_validation(tmp_path):
    good = dict(tau=np.ones(K), g=0.0, eps=0.0, M=np.ones((K, 5, 3)))
    for bad, msg in ((dict(tau=np.zeros(K)), "tau"), (dict(g=1.5), "gate g"), (dict(eps=-0.1), "gate eps"),
                     (dict(M=np.ones((K, 4, 3))), "shape"), (dict(M=-np.ones((K, 5, 3))), ">= 0"),
                     (dict(distance_edges=(0, 2, 1, 3, 4, 5)), "increasing"),
                     (dict(class_names=("a", "b")), "classes"),
                     # a string is no class list (it would read as one class per letter)
                     (dict(class_names="wall"), "class_names must be a list of class names, got the string 'wall'"),
                     (dict(class_names=("a", "b", "a", "c")), "lists 'a' more than once")):
        with pytest.raises(ValueError, match=msg):
            GLFSParams(**{**good, **bad})
    with pytest.raises(ValueError, match="not found"):
        GLFSParams.load(tmp_path / "missing.json")
    (tmp_path / "broken.json").write_text("{not json")
    with pytest.raises(ValueError, match="corrupt"):
        GLFSParams.load(tmp_path / "broken.json")
    with pytest.raises(ValueError, match=".json or .npz"):
        GLFSParams(**good).save(tmp_path / "glfs.yaml")
