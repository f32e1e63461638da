"""Batched fusion strategies (mapping.fusion): properties, reductions of GLFS, the paper's
double-counting example, differentiability and bad input."""
import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from calnav.mapping.fusion import LAPLACE_MU, Strategy, fuse, get_strategy
from calnav.mapping.registry import FUSIONS

NAMES = FUSIONS.names()
GATES = {"glfs": {"g": 0.4, "eps": 0.3}}


def _fuse(logits, name, **kw):
    return fuse(logits, name, **{**GATES.get(name, {}), **kw})


def test_every_registered_name_loads_its_strategy():
    """Each lazy reference of ``FUSIONS`` resolves to the ``Strategy`` of that name (a reference
    to a missing or another strategy fails here, not in the first run that names it)."""
    assert len(NAMES) == 5
    for name in NAMES:
        strategy = get_strategy(name)
        assert isinstance(strategy, Strategy) and strategy.name == name and FUSIONS.get(name) is strategy
    assert get_strategy(strategy) is strategy   # a Strategy passes through


@st.composite
def observation_sets(draw):
    n, t, k = draw(st.integers(1, 4)), draw(st.integers(1, 6)), draw(st.integers(2, 6))
    kind = draw(st.sampled_from(["normal", "huge", "onehot", "tiny_probs"]))
    if kind == "normal":
        logits = draw(arrays(np.float32, (n, t, k), elements=st.floats(-20, 20, width=32)))
    elif kind == "huge":
        logits = draw(arrays(np.float32, (n, t, k), elements=st.floats(-1e6, 1e6, width=32)))
    elif kind == "onehot":  # probabilities exactly one-hot after the softmax
        idx = draw(arrays(np.int64, (n, t), elements=st.integers(0, k - 1)))
        logits = np.eye(k, dtype=np.float32)[idx] * 1e4
    else:  # near-zero probabilities for all but one class
        logits = draw(arrays(np.float32, (n, t, k), elements=st.floats(-200, -100, width=32)))
        logits[..., 0] = 0.0
    mask = draw(arrays(np.bool_, (n, t)))
    weights = draw(arrays(np.float32, (n, t), elements=st.floats(0, 1e3, width=32)))
    first = draw(st.integers(0, t - 1))
    mask[:, first] = True  # at least one real observation per voxel ...
    weights[:, first] = np.maximum(weights[:, first], 1e-3)  # ... with a positive weight
    tau = draw(st.one_of(st.floats(0.05, 20), arrays(np.float32, (k,), elements=st.floats(0.0625, 20, width=32))))
    return torch.from_numpy(logits), torch.from_numpy(mask), torch.from_numpy(weights), tau


@settings(max_examples=60, deadline=None)
@given(obs=observation_sets(), name=st.sampled_from(NAMES), g=st.floats(0, 1), eps=st.floats(0, 1))
def test_fused_vectors_are_finite_distributions(obs, name, g, eps):
    logits, mask, weights, tau = obs
    gates = {"g": g, "eps": eps} if name == "glfs" else {}
    for w in (None, weights):
        probs = fuse(logits, name, mask=mask, weights=w, temperature=tau, **gates)
        assert probs.shape == (logits.shape[0], logits.shape[2])
        assert torch.isfinite(probs).all()
        assert (probs >= 0).all()
        assert torch.allclose(probs.sum(-1), torch.ones(len(probs)), atol=1e-5)


def _random_logits(n=50, t=7, k=5, seed=0, scale=3.0):
    return torch.from_numpy(np.random.default_rng(seed).normal(0, scale, (n, t, k)).astype(np.float64))


def test_glfs_reduces_to_rbu_geometric_mean_and_averaging():
    z = _random_logits()
    assert torch.allclose(fuse(z, "glfs", g=1.0, eps=1.0), fuse(z, "rbu"), atol=1e-10)
    assert torch.allclose(fuse(z, "glfs", g=1.0, eps=0.0), fuse(z, "geometric_mean"), atol=1e-10)
    assert torch.allclose(fuse(z, "glfs", g=0.0, eps=0.0), fuse(z, "averaging"), atol=1e-10)


def test_glfs_approaches_histogram_as_tau_goes_to_zero():
    z = _random_logits(k=4)
    gap = (z.topk(2, dim=-1).values[..., 0] - z.topk(2, dim=-1).values[..., 1]).min()
    assert gap > 1e-3  # the argmax is unambiguous, so softmax(z / tau) -> one-hot
    hist = fuse(z, "histogram")
    errors = [(fuse(z, "glfs", g=0.0, eps=0.0, temperature=tau) - hist).abs().max().item() for tau in (1.0, 0.1, 1e-5)]
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 1e-6


def test_rbu_and_averaging_are_order_invariant():
    z = _random_logits(t=9)
    w = torch.rand(z.shape[:2], dtype=z.dtype)
    perm = torch.randperm(z.shape[1])
    for name in ("rbu", "averaging", "geometric_mean", "histogram"):
        assert torch.allclose(fuse(z, name, weights=w), fuse(z[:, perm], name, weights=w[:, perm]), atol=1e-10)


def test_double_counting_example_of_the_paper():
    """50 views of (0.49, 0.51): RBU becomes confident, averaging stays at 0.51."""
    p = torch.tensor([0.49, 0.51], dtype=torch.float64)
    logits = torch.log(p).expand(1, 50, 2).clone()
    rbu = fuse(logits, "rbu")[0, 1].item()
    # by hand: smoothed p' = (p + mu) / (1 + 2 mu); RBU = sigmoid(50 log(p'_2 / p'_1))
    expected = 1.0 / (1.0 + ((0.49 + LAPLACE_MU) / (0.51 + LAPLACE_MU)) ** 50)
    assert rbu == pytest.approx(expected, abs=1e-9)
    assert rbu == pytest.approx(0.8804, abs=1e-4)
    assert fuse(logits, "averaging")[0, 1].item() == pytest.approx(0.51, abs=1e-9)
    assert fuse(logits, "geometric_mean")[0, 1].item() == pytest.approx(0.51, abs=2e-3)


def test_weights_act_as_repeated_observations():
    z = _random_logits(n=10, t=2, k=3)
    w = torch.tensor([[3.0, 1.0]], dtype=z.dtype).expand(10, 2)
    repeated = torch.cat([z[:, :1]] * 3 + [z[:, 1:]], dim=1)
    for name in NAMES:
        assert torch.allclose(_fuse(z, name, weights=w), _fuse(repeated, name), atol=1e-10), name


def test_masked_observations_are_ignored():
    z = _random_logits(n=6, t=4)
    mask = torch.tensor([True, False, True, False]).expand(6, 4)
    garbage = z.clone()
    garbage[:, 1] = float("nan")
    garbage[:, 3] = 1e30
    for name in NAMES:
        assert torch.allclose(_fuse(garbage, name, mask=mask), _fuse(z[:, [0, 2]], name), atol=1e-10), name


def test_zero_total_weight_reads_uniform():
    z = _random_logits(n=2, t=3, k=4)
    for name in NAMES:
        assert torch.allclose(_fuse(z, name, weights=torch.zeros(2, 3, dtype=z.dtype)), torch.full((2, 4), 0.25, dtype=z.dtype))


def test_vector_temperature_scales_each_class():
    z = _random_logits(n=5, t=3, k=3)
    tau = torch.tensor([0.5, 1.0, 2.0], dtype=z.dtype)
    assert torch.allclose(fuse(z, "averaging", temperature=tau), fuse(z / tau, "averaging"), atol=1e-12)
    assert torch.allclose(fuse(z, "rbu", temperature=2.0), fuse(z / 2.0, "rbu"), atol=1e-12)


def test_differentiable_wrt_temperature_weights_and_gates():
    z = _random_logits(n=20, t=5, k=4)
    tau = torch.full((4,), 1.3, dtype=z.dtype, requires_grad=True)
    w = torch.rand(20, 5, dtype=z.dtype, requires_grad=True)
    g = torch.tensor(0.5, dtype=z.dtype, requires_grad=True)
    eps = torch.tensor(0.2, dtype=z.dtype, requires_grad=True)
    target = torch.randint(0, 4, (20,))
    loss = -torch.log(fuse(z, "glfs", weights=w, temperature=tau, g=g, eps=eps)[torch.arange(20), target]).mean()
    loss.backward()
    for p in (tau, w, g, eps):
        assert p.grad is not None and torch.isfinite(p.grad).all() and p.grad.abs().sum() > 0
    for name in ("rbu", "averaging", "geometric_mean"):
        t = torch.tensor(1.5, dtype=z.dtype, requires_grad=True)
        fuse(z, name, temperature=t)[:, 0].sum().backward()
        assert t.grad is not None and math.isfinite(t.grad.item()) and t.grad.item() != 0.0


def test_bad_input_raises_clear_errors():
    z = _random_logits(n=3, t=2, k=4).float()
    with pytest.raises(ValueError, match="^unknown fusion strategy 'bayes' for mapping.fusion; valid choices: rbu, "
                                         "averaging, histogram, geometric_mean, glfs$"):
        fuse(z, "bayes")
    with pytest.raises(ValueError, match="valid choices"):
        get_strategy("max")
    with pytest.raises(ValueError, match="needs both gates"):
        fuse(z, "glfs")
    with pytest.raises(ValueError, match="takes neither"):
        fuse(z, "rbu", g=0.5, eps=0.5)
    with pytest.raises(ValueError, match=r"in \[0, 1\]"):
        fuse(z, "glfs", g=1.5, eps=0.0)
    with pytest.raises(ValueError, match=r"\(N, T, K\)"):
        fuse(z[0], "rbu")
    with pytest.raises(ValueError, match="temperature"):
        fuse(z, "rbu", temperature=torch.ones(3))
    with pytest.raises(ValueError, match="> 0"):
        fuse(z, "rbu", temperature=0.0)
    with pytest.raises(ValueError, match="weights"):
        fuse(z, "rbu", weights=torch.ones(3, 3))
    with pytest.raises(ValueError, match=">= 0"):
        fuse(z, "rbu", weights=-torch.ones(3, 2))
    with pytest.raises(ValueError, match="mask"):
        fuse(z, "rbu", mask=torch.ones(3, 2))
    with pytest.raises(ValueError, match="finite"):
        fuse(torch.full_like(z, float("nan")), "averaging")


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("half", [torch.float16, torch.bfloat16])
def test_half_precision_logits_fuse_in_float32(name, half):
    """fp16 / bf16 logits (as the observation caches store them) fuse like the float32 tensor
    of the same values, and the result is float32."""
    from calnav.mapping.fusion import fuse_flat

    gen = torch.Generator().manual_seed(3)
    z = (3 * torch.randn(4, 5, 6, generator=gen)).to(half)
    kw = {"g": 0.3, "eps": 0.2} if get_strategy(name).gated else {}
    tau = torch.linspace(0.5, 2.0, 6)
    out = fuse(z, name, temperature=tau, **kw)
    assert out.dtype == torch.float32
    assert torch.equal(out, fuse(z.float(), name, temperature=tau, **kw))
    voxel = torch.arange(4).repeat_interleave(5)
    flat = fuse_flat(z.reshape(20, 6), voxel, 4, name, temperature=tau, **kw)
    assert flat.dtype == torch.float32
    assert torch.equal(flat, fuse_flat(z.float().reshape(20, 6), voxel, 4, name, temperature=tau, **kw))
