"""calnav's learned segmenters on CUDA give the CPU's logits (float32: TensorFloat-32 off by
default, ``segmenter.tf32``). Needs a CUDA GPU; run where one is (the GPU machine of a session:
``PYTHONPATH=$PWD python3 -m pytest -q tests/agent/test_segmenters_cuda.py``, needing only torch,
numpy and OpenCV). Measured on an NVIDIA H200 (torch 2.11, 2026-11-26): max |logit difference|
4e-6 to 9e-6 and every pixel's class equal at 160x120 and 640x480; with TF32 allowed (torch's
default for cuDNN) 9e-3 to 1.4e-2 and 0.03 % of the pixels changed class."""
import numpy as np
import pytest
import torch

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")


@pytest.mark.parametrize("name", ["learned_rgb", "learned_rgbd"])
@pytest.mark.parametrize("size", [(160, 120), (640, 480)])
def test_cuda_logits_equal_the_cpus(name, size):
    from calnav.agent.segmenters import make_segmenter

    w, h = size
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    depth = rng.uniform(0.5, 5.0, (h, w)).astype(np.float32)
    cpu = make_segmenter(name, None, device="cpu").segment(rgb, depth)
    gpu = make_segmenter(name, None, device="cuda").segment(rgb, depth)
    assert gpu.dtype == np.float32 and gpu.shape == cpu.shape == (h, w, 18)
    assert np.abs(gpu - cpu).max() < 1e-4
    assert (gpu.argmax(-1) == cpu.argmax(-1)).all()
