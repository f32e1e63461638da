"""Logit scaling (paper Sec. V-C): temperature (one scalar) or vector scaling (one temperature
per class), applied to the segmentation logits before the softmax, for every fusion strategy.

All functions are pure torch and differentiable w.r.t. the temperature (3D temperature / vector
scaling fits tau *through* the fusion; GLFS learns it end to end).
"""
from __future__ import annotations

import numpy as np
import torch

# Scaled logits are clamped to +-this so that z / tau never overflows to inf (inf - inf = NaN in
# the softmax). Any logit gap above ~100 already gives a one-hot softmax, so nothing is lost.
MAX_SCALED_LOGIT = 1e30


def as_temperature(temperature, num_classes: int, *, dtype: torch.dtype = torch.float32,
                   device: torch.device | str = "cpu") -> torch.Tensor:
    """Validate a temperature and return it as a tensor: () for a scalar, (K,) for a vector.

    temperature: float, 0-d/1-d array or tensor; every entry finite and > 0. A tensor that
    requires grad is returned as is (same graph), only moved/cast when needed.
    """
    if isinstance(temperature, torch.Tensor):
        tau = temperature.to(device=device, dtype=dtype)
    else:
        tau = torch.as_tensor(np.asarray(temperature, dtype=np.float64), dtype=dtype, device=device)
    if tau.ndim == 1 and tau.shape[0] == 1:
        tau = tau[0]
    if tau.ndim not in (0, 1) or (tau.ndim == 1 and tau.shape[0] != num_classes):
        raise ValueError(
            f"temperature must be a scalar or a ({num_classes},) vector (one per class), got shape {tuple(tau.shape)}")
    with torch.no_grad():
        if not bool(torch.isfinite(tau).all()) or bool((tau <= 0).any()):
            raise ValueError(f"temperature must be finite and > 0, got {tau.detach().cpu().numpy()}")
    return tau


def scale_logits(logits: torch.Tensor, temperature: torch.Tensor) -> torch.Tensor:
    """z / tau, broadcast over the last (class) axis. logits: (..., K); temperature: () or (K,)."""
    return (logits / temperature).clamp(-MAX_SCALED_LOGIT, MAX_SCALED_LOGIT)
