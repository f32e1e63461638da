"""Differentiable calibration error (DECE, Bohdal et al., Meta-Calibration; mDECE, its mean over
classes: paper Sec. V-D) for training calibration through the fusion (the GLFS loss uses
0.5 * mDECE).

Inputs: probs (N, K) float tensor (rows are probability vectors), labels (N,) int64.

- Soft binning of the top-label confidence c_i = max_k probs[i, k] into M bins:
  o_ij = softmax_j((c_i * j + b_j) / t_b), j = 1..M, b = cumsum(-linspace(0, 1, M + 1)[:-1]).
  Consecutive logits differ by c_i - (j - 1) / M, so as t_b -> 0 the membership becomes the
  hard bin [(j - 1) / M, j / M) of ``mapping.metrics``.
- Soft accuracy from the soft rank of the true class:
  rank_i = 0.5 + sum_k sigmoid(t_a (p_ik - p_iy)) (the true class itself adds 0.5),
  acc_i = relu(2 - rank_i) -> 1 when y is the top class, 0 otherwise, as t_a -> inf.
- DECE = sum_j (sum_i o_ij / N) |sum_i o_ij acc_i / sum_i o_ij - sum_i o_ij c_i / sum_i o_ij|
       = sum_j |sum_i o_ij (acc_i - c_i)| / N.
- mDECE = DECE within each ground-truth class present in ``labels``, averaged over classes.

Memory: rank needs an (N, K) temporary; callers chunk very large N themselves.
"""
from __future__ import annotations

import torch

DEFAULT_BINS = 10
DEFAULT_T_A = 100.0     # the authors' soft-rank temperature
DEFAULT_T_B = 0.01      # the authors' soft-binning temperature


def soft_bins(conf: torch.Tensor, n_bins: int = DEFAULT_BINS, t_b: float = DEFAULT_T_B) -> torch.Tensor:
    """(N,) confidences -> (N, n_bins) soft bin memberships (rows sum to 1)."""
    cuts = torch.linspace(0.0, 1.0, n_bins + 1, dtype=conf.dtype, device=conf.device)[:-1]
    b = torch.cumsum(-cuts, dim=0)
    j = torch.arange(1, n_bins + 1, dtype=conf.dtype, device=conf.device)
    return torch.softmax((conf[:, None] * j + b) / t_b, dim=1)


def soft_accuracy(probs: torch.Tensor, labels: torch.Tensor, t_a: float = DEFAULT_T_A) -> torch.Tensor:
    """(N,) differentiable "is the label the top class" in [0, 1]."""
    p_true = probs.gather(1, labels[:, None])
    rank = 0.5 + torch.sigmoid(t_a * (probs - p_true)).sum(dim=1)  # the true class's own term adds 0.5
    return torch.relu(2.0 - rank)


def _check(probs: torch.Tensor, labels: torch.Tensor) -> None:
    if probs.ndim != 2 or labels.ndim != 1 or len(probs) != len(labels):
        raise ValueError(f"need probs (N, K) and labels (N,), got {tuple(probs.shape)} and {tuple(labels.shape)}")
    if len(labels) == 0:
        raise ValueError("no samples")
    if labels.min() < 0 or labels.max() >= probs.shape[1]:
        raise ValueError(f"labels must be class ids in [0, {probs.shape[1]})")


def dece(probs: torch.Tensor, labels: torch.Tensor, n_bins: int = DEFAULT_BINS, t_a: float = DEFAULT_T_A,
         t_b: float = DEFAULT_T_B) -> torch.Tensor:
    """Differentiable ECE (scalar tensor)."""
    _check(probs, labels)
    conf = probs.max(dim=1).values
    o = soft_bins(conf, n_bins, t_b)
    gap = (o * (soft_accuracy(probs, labels, t_a) - conf)[:, None]).sum(dim=0)
    return gap.abs().sum() / len(labels)


def mdece(probs: torch.Tensor, labels: torch.Tensor, n_bins: int = DEFAULT_BINS, t_a: float = DEFAULT_T_A,
          t_b: float = DEFAULT_T_B) -> torch.Tensor:
    """Differentiable mECE: DECE within each ground-truth class present, averaged."""
    _check(probs, labels)
    conf = probs.max(dim=1).values
    o = soft_bins(conf, n_bins, t_b)                                        # (N, M)
    weighted = o * (soft_accuracy(probs, labels, t_a) - conf)[:, None]     # (N, M)
    k = probs.shape[1]
    per_class = torch.zeros(k, n_bins, dtype=probs.dtype, device=probs.device).index_add_(0, labels, weighted)
    counts = torch.bincount(labels, minlength=k).to(probs.dtype)
    present = counts > 0
    return (per_class.abs().sum(dim=1)[present] / counts[present]).mean()
