"""Semantic fusion strategies (paper Sec. III-B, V-A, V-D), chosen by name (``mapping.registry.FUSIONS``).

Every strategy is two pure torch functions over *accumulators* -- linear sums over the
observations of one voxel, so fusion is incremental:

- ``A`` (K): sum_t w_t log p'_t, with Laplace smoothing p' = (p + mu) / (1 + K mu);
- ``B`` (K): sum_t w_t p_t (or w_t onehot(argmax p_t) for ``histogram``);
- ``W`` (1): sum_t w_t.

``increments(terms, w)`` gives one observation's contribution to each accumulator and
``readout(acc, g, eps)`` turns accumulators into fused probabilities (N, K). The same two
functions serve the batched differentiable ``fuse`` (sum over the T axis) and the incremental
``SemanticVoxelMap`` (``index_add_`` into voxel attributes), so the two agree by construction.

| name           | accumulators | read-out                                            |
| rbu            | A            | softmax(A)  (uniform prior)                          |
| geometric_mean | A, W         | softmax(A / W)                                       |
| averaging      | B, W         | B / W                                                |
| histogram      | B (votes), W | B / W                                                |
| glfs           | A, B, W      | s ~ G softmax(alpha A) + (1 - G) alpha B, alpha = (1 - eps) / W + eps |

GLFS reduces to rbu at (G, eps) = (1, 1), geometric mean at (1, 0), averaging at (0, 0)
(tau = 1, w = 1) and to histogram as tau -> 0 at (0, 0). A voxel whose total weight is 0
reads out uniform.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Callable, Mapping

import torch

from calnav.mapping.config import LAPLACE_MU  # noqa: F401  (re-exported: the smoothing constant's default)
from calnav.mapping.registry import FUSIONS
from calnav.mapping.scaling import as_temperature, scale_logits

ACCUMULATOR_NAMES: tuple[str, ...] = ("A", "B", "W")


def accumulator_channels(name: str, num_classes: int) -> int:
    """Channels of accumulator ``name``: K for A and B, 1 for W."""
    return 1 if name == "W" else num_classes


class ObservationTerms:
    """Per-observation quantities derived lazily from *scaled* logits z (..., K).

    p: softmax(z); log_p: log of the Laplace-smoothed p'; onehot: onehot(argmax z).
    """

    def __init__(self, scaled_logits: torch.Tensor, mu: float = LAPLACE_MU):
        self.z = scaled_logits
        self.mu = float(mu)

    @cached_property
    def p(self) -> torch.Tensor:
        return torch.softmax(self.z, dim=-1)

    @cached_property
    def log_p(self) -> torch.Tensor:
        k = self.z.shape[-1]
        return torch.log(self.p + self.mu) - torch.log1p(torch.tensor(k * self.mu, dtype=self.z.dtype))

    @cached_property
    def onehot(self) -> torch.Tensor:
        idx = self.z.argmax(dim=-1, keepdim=True)
        return torch.zeros_like(self.z).scatter_(-1, idx, 1.0)


def _safe_total(w_sum: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(positive, W with zeros replaced by 1): avoids 0/0 and NaN gradients for unobserved rows."""
    positive = w_sum > 0
    return positive, torch.where(positive, w_sum, torch.ones_like(w_sum))


def normalise(s: torch.Tensor) -> torch.Tensor:
    """s / sum(s) over the last axis; rows with no mass (or a non-finite sum) become uniform."""
    total = s.sum(dim=-1, keepdim=True)
    ok = (total > 0) & torch.isfinite(total)
    safe = torch.where(ok, total, torch.ones_like(total))
    return torch.where(ok, s / safe, torch.full_like(s, 1.0 / s.shape[-1]))


# ----------------------------------------------------------------------- increments
def _inc_log(terms: ObservationTerms, w: torch.Tensor) -> dict[str, torch.Tensor]:
    return {"A": w[..., None] * terms.log_p}


def _inc_log_w(terms: ObservationTerms, w: torch.Tensor) -> dict[str, torch.Tensor]:
    return {"A": w[..., None] * terms.log_p, "W": w[..., None]}


def _inc_prob(terms: ObservationTerms, w: torch.Tensor) -> dict[str, torch.Tensor]:
    return {"B": w[..., None] * terms.p, "W": w[..., None]}


def _inc_vote(terms: ObservationTerms, w: torch.Tensor) -> dict[str, torch.Tensor]:
    return {"B": w[..., None] * terms.onehot, "W": w[..., None]}


def _inc_glfs(terms: ObservationTerms, w: torch.Tensor) -> dict[str, torch.Tensor]:
    wk = w[..., None]
    return {"A": wk * terms.log_p, "B": wk * terms.p, "W": wk}


# ------------------------------------------------------------------------- read-outs
def _read_rbu(acc: Mapping[str, torch.Tensor], g=None, eps=None) -> torch.Tensor:
    return torch.softmax(acc["A"], dim=-1)


def _read_geometric(acc: Mapping[str, torch.Tensor], g=None, eps=None) -> torch.Tensor:
    _, w = _safe_total(acc["W"])
    return torch.softmax(acc["A"] / w, dim=-1)  # A = 0 where W = 0 -> uniform


def _read_mean(acc: Mapping[str, torch.Tensor], g=None, eps=None) -> torch.Tensor:
    return normalise(acc["B"])  # B / W: sum_k B_k = W exactly (up to rounding)


def _read_glfs(acc: Mapping[str, torch.Tensor], g=None, eps=None) -> torch.Tensor:
    positive, w = _safe_total(acc["W"])
    alpha = (1.0 - eps) / w + eps
    s = g * torch.softmax(alpha * acc["A"], dim=-1) + (1.0 - g) * alpha * acc["B"]
    s = torch.where(positive, s, torch.ones_like(s))
    return normalise(s)


@dataclass(frozen=True)
class Strategy:
    """A fusion strategy: the accumulators it needs and its two pure functions."""

    name: str
    accumulators: tuple[str, ...]
    increments: Callable[[ObservationTerms, torch.Tensor], dict[str, torch.Tensor]]
    readout: Callable[..., torch.Tensor]
    gated: bool = False          # needs the GLFS gates (g, eps)
    differentiable: bool = True  # False: argmax votes (no gradient w.r.t. temperature)
    votes: bool = False          # B sums onehot(argmax) votes instead of probabilities

    def channels(self, num_classes: int) -> dict[str, int]:
        return {a: accumulator_channels(a, num_classes) for a in self.accumulators}


# The strategies, registered by name in ``mapping.registry.FUSIONS`` (lazily: a config names
# one without importing torch).
RBU = Strategy("rbu", ("A",), _inc_log, _read_rbu)
AVERAGING = Strategy("averaging", ("B", "W"), _inc_prob, _read_mean)
HISTOGRAM = Strategy("histogram", ("B", "W"), _inc_vote, _read_mean, differentiable=False, votes=True)
GEOMETRIC_MEAN = Strategy("geometric_mean", ("A", "W"), _inc_log_w, _read_geometric)
GLFS = Strategy("glfs", ("A", "B", "W"), _inc_glfs, _read_glfs, gated=True)


def get_strategy(name: str | Strategy) -> Strategy:
    """The strategy registered as ``name`` (``mapping.registry.FUSIONS``), or ``name`` itself
    when it is a ``Strategy``; a ValueError names the valid choices."""
    if isinstance(name, Strategy):
        return name
    return FUSIONS.get(name)


def check_gates(strategy: Strategy, g, eps, dtype: torch.dtype = torch.float32,
                device: torch.device | str = "cpu") -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """Validate the GLFS gates: required (in [0, 1]) for gated strategies, forbidden otherwise."""
    if not strategy.gated:
        if g is not None or eps is not None:
            raise ValueError(f"g and eps are GLFS gates; strategy {strategy.name!r} takes neither")
        return None, None
    if g is None or eps is None:
        raise ValueError(f"strategy {strategy.name!r} needs both gates g and eps (floats in [0, 1])")
    out = []
    for name, v in (("g", g), ("eps", eps)):
        t = v.to(device=device, dtype=dtype) if isinstance(v, torch.Tensor) else torch.tensor(float(v), dtype=dtype, device=device)
        if t.ndim != 0:
            raise ValueError(f"GLFS gate {name} must be a scalar, got shape {tuple(t.shape)}")
        with torch.no_grad():
            if not 0.0 <= float(t) <= 1.0:
                raise ValueError(f"GLFS gate {name} must be in [0, 1], got {float(t)}")
        out.append(t)
    return out[0], out[1]


# Floating dtypes too narrow to fuse in: the clamp bound and log-space sums overflow float16
# (max 65504), and bfloat16 keeps 8 bits of mantissa. Such logits (e.g. fp16 observation caches)
# are fused in float32.
HALF_DTYPES = (torch.float16, torch.bfloat16)


def _check_logits(logits, layout: str) -> torch.Tensor:
    """``logits`` after checking it is a float tensor of layout ``layout`` (the number of axes
    is the layout's) with at least 2 classes on the last axis; half-precision logits are
    returned as float32 (differentiably), the dtype everything is then computed in."""
    ndim = layout.count(",") + 1
    if not isinstance(logits, torch.Tensor) or logits.ndim != ndim or not logits.is_floating_point():
        desc = f"{tuple(logits.shape)} {logits.dtype}" if isinstance(logits, torch.Tensor) else type(logits).__name__
        raise ValueError(f"logits must be a float {layout} tensor, got {desc}")
    k = logits.shape[-1]
    if k < 2:
        raise ValueError(f"need at least 2 classes, got K = {k}")
    return logits.float() if logits.dtype in HALF_DTYPES else logits


def _scaled_inputs(strat: Strategy, logits: torch.Tensor, weights, temperature, g, eps, weight_layout: str,
                   mask: torch.Tensor | None = None, what: str = "logits"):
    """The input checks ``fuse`` and ``fuse_flat`` share, on logits already checked by
    ``_check_logits``: the gates, temperature and weights (one per observation, layout
    ``weight_layout``); then scales the logits, applies the optional padding ``mask`` (masked
    entries get logits and weight 0) and checks the result is finite with weights >= 0.
    Returns (scaled logits z, weights w, g, eps)."""
    *obs_shape, k = logits.shape
    obs_shape = tuple(obs_shape)
    dtype, device = logits.dtype, logits.device
    g_t, eps_t = check_gates(strat, g, eps, dtype, device)
    tau = as_temperature(temperature, k, dtype=dtype, device=device)
    w = torch.ones(obs_shape, dtype=dtype, device=device) if weights is None else weights.to(dtype)
    if w.shape != obs_shape:
        raise ValueError(f"weights must have shape {weight_layout} = {obs_shape}, got {tuple(w.shape)}")
    z = scale_logits(logits, tau)
    if mask is not None:
        if mask.shape != obs_shape or mask.dtype != torch.bool:
            raise ValueError(f"mask must be a bool {weight_layout} = {obs_shape} tensor, got {tuple(mask.shape)} {mask.dtype}")
        z = torch.where(mask[..., None], z, torch.zeros((), dtype=dtype, device=device))
        w = torch.where(mask, w, torch.zeros((), dtype=dtype, device=device))
    with torch.no_grad():
        if not bool(torch.isfinite(z).all()) or not bool(torch.isfinite(w).all()) or bool((w < 0).any()):
            raise ValueError(f"{what} must be finite and weights finite and >= 0")
    return z, w, g_t, eps_t


def fuse(logits: torch.Tensor, strategy: str | Strategy, *, mask: torch.Tensor | None = None,
         weights: torch.Tensor | None = None, temperature=1.0, g=None, eps=None,
         mu: float = LAPLACE_MU) -> torch.Tensor:
    """Batched fusion of T observations per voxel -> probs (N, K), differentiable w.r.t.
    temperature, weights, g and eps (histogram's argmax is not).

    logits: (N, T, K) float tensor of raw segmentation logits (float16 / bfloat16: fused in float32).
    mask: (N, T) bool, False = padding (ignored). weights: (N, T) >= 0 sample weights.
    temperature: scalar or (K,) (vector scaling). g, eps: GLFS gates in [0, 1] (glfs only).
    """
    strat = get_strategy(strategy)
    logits = _check_logits(logits, "(N, T, K)")
    z, w, g_t, eps_t = _scaled_inputs(strat, logits, weights, temperature, g, eps, "(N, T)", mask=mask,
                                      what="logits (unmasked entries)")
    inc = strat.increments(ObservationTerms(z, mu), w)
    acc = {name: v.sum(dim=1) for name, v in inc.items()}
    return strat.readout(acc, g=g_t, eps=eps_t)


def fuse_flat(logits: torch.Tensor, voxel: torch.Tensor, num_voxels: int, strategy: str | Strategy, *,
              weights: torch.Tensor | None = None, temperature=1.0, g=None, eps=None,
              mu: float = LAPLACE_MU) -> torch.Tensor:
    """Fusion of a flat list of observations -> probs (num_voxels, K): the same accumulators as
    ``fuse`` summed with ``index_add`` instead of over a padded T axis, so memory and time follow
    the number of observations (no padding to the busiest voxel). Differentiable like ``fuse``.

    logits: (n, K) float raw logits (float16 / bfloat16: fused in float32); voxel: (n,) int64 voxel index in [0, num_voxels) of each
    observation; weights: (n,) >= 0 or None (= 1). A voxel without observations reads uniform.
    """
    strat = get_strategy(strategy)
    logits = _check_logits(logits, "(n, K)")
    n = logits.shape[0]
    if voxel.shape != (n,) or voxel.dtype != torch.int64:
        raise ValueError(f"voxel must be an int64 (n,) = ({n},) tensor, got {tuple(voxel.shape)} {voxel.dtype}")
    if n and (int(voxel.min()) < 0 or int(voxel.max()) >= num_voxels):
        raise ValueError(f"voxel indices must be in [0, {num_voxels})")
    z, w, g_t, eps_t = _scaled_inputs(strat, logits, weights, temperature, g, eps, "(n,)")
    dtype, device = logits.dtype, logits.device
    inc = strat.increments(ObservationTerms(z, mu), w)
    acc = {name: torch.zeros((num_voxels, v.shape[-1]), dtype=dtype, device=device).index_add(0, voxel, v)
           for name, v in inc.items()}
    return strat.readout(acc, g=g_t, eps=eps_t)
