"""Sample weighting (paper Sec. V-B, V-D): a weight w_t >= 0 per observation from the predicted
class, the voxel's distance to the camera and the incidence angle of the viewing ray on the
surface, chosen by name (``mapping.registry.WEIGHTINGS``); every function is pure torch (the
LUT is differentiable w.r.t. M, for GLFS training).

- ``none``: w = 1.
- ``lut``: the GLFS table, w = max(M, 0)[predicted class, distance bin, angle bin]. Authors'
  bins: distance edges 0, 1, ..., 5 m (beyond the last edge -> last bin), incidence-angle edges
  0, 30, 60, 90 deg. M starts at 1.
- ``distance``: inverse-square falloff, w = min(1, (d_ref / d)^2): full weight up to d_ref,
  then the fraction of a fixed-size patch's pixels that still land on it (depth noise of
  stereo / ToF sensors also grows ~ d^2).
- ``incidence``: Curless & Levoy (1996): w = cos(incidence angle), the foreshortening of the
  surface patch seen by the pixel.
- ``sweet_spot``: quadratic around the segmentation model's best distance (Zheng et al.,
  paper ref. [9981300]): w = 1 - ((d - d_best) / halfwidth)^2.
The analytic weights are floored at ``min_weight`` so that no observation counts for nothing.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from calnav.mapping.config import ANGLE_EDGES_DEG, DISTANCE_EDGES_M, MappingConfig  # noqa: F401 (the LUT's bins)
from calnav.mapping.registry import AUTO_WEIGHTING, FUSIONS, WEIGHTINGS, check_weighting


@dataclass
class WeightingParams:
    """Parameters of every weighting (unused ones are ignored).

    lut: (K, n_dist, n_angle) tensor M (``lut`` only); distance_edges / angle_edges_deg: the
    LUT's bin edges (n_dist + 1 and n_angle + 1 increasing values, first 0).
    """

    lut: torch.Tensor | None = None
    distance_edges: tuple[float, ...] = DISTANCE_EDGES_M
    angle_edges_deg: tuple[float, ...] = ANGLE_EDGES_DEG
    distance_ref_m: float = MappingConfig.distance_ref_m
    sweet_spot_m: float = MappingConfig.sweet_spot_m
    sweet_spot_halfwidth_m: float = MappingConfig.sweet_spot_halfwidth_m
    min_weight: float = MappingConfig.min_sample_weight

    @classmethod
    def from_config(cls, cfg, lut: torch.Tensor | None = None,
                    distance_edges: tuple[float, ...] = DISTANCE_EDGES_M,
                    angle_edges_deg: tuple[float, ...] = ANGLE_EDGES_DEG) -> "WeightingParams":
        """From a ``MappingConfig`` (analytic parameters) plus an optional LUT."""
        return cls(lut=lut, distance_edges=tuple(distance_edges), angle_edges_deg=tuple(angle_edges_deg),
                   distance_ref_m=cfg.distance_ref_m, sweet_spot_m=cfg.sweet_spot_m,
                   sweet_spot_halfwidth_m=cfg.sweet_spot_halfwidth_m, min_weight=cfg.min_sample_weight)


def bin_index(values: torch.Tensor, edges: tuple[float, ...]) -> torch.Tensor:
    """(n,) int64 bin of each value for bins [e0, e1), [e1, e2), ...; values beyond the last
    edge go to the last bin, below the first to the first."""
    inner = torch.tensor(edges[1:-1], dtype=values.dtype, device=values.device)
    return torch.bucketize(values, inner, right=True)


def none_weights(pred, distance_m, angle_deg, params: WeightingParams) -> torch.Tensor:
    return torch.ones(distance_m.shape, dtype=distance_m.dtype, device=distance_m.device)


def lut_table(params: WeightingParams) -> torch.Tensor:
    """The ``lut`` weighting's table max(M, 0) (K, n_dist, n_angle), its shape checked against the
    bin edges (the voxel map's compiled look-up indexes it without bounds checks)."""
    if params.lut is None:
        raise ValueError("weighting 'lut' needs a look-up table M (K, n_dist, n_angle); see mapping.glfs.GLFSParams")
    bins = (len(params.distance_edges) - 1, len(params.angle_edges_deg) - 1)
    if params.lut.ndim != 3 or tuple(params.lut.shape[1:]) != bins:
        raise ValueError(f"the LUT M must have shape (K, n_dist, n_angle) = (K, {bins[0]}, {bins[1]}) for its bin "
                         f"edges, got {tuple(params.lut.shape)}")
    return params.lut.clamp_min(0.0)


def lut_cells(distance_m: torch.Tensor, angle_deg: torch.Tensor, params: WeightingParams) -> torch.Tensor:
    """(...) int64 (distance bin, angle bin) cell of each observation within its class's slice
    of the flat LUT: the weight is ``lut_table(params).reshape(-1)[pred * n_dist * n_angle + cell]``."""
    n_angle = len(params.angle_edges_deg) - 1
    return bin_index(distance_m, params.distance_edges) * n_angle + bin_index(angle_deg, params.angle_edges_deg)


def lut_weights(pred, distance_m, angle_deg, params: WeightingParams) -> torch.Tensor:
    m = lut_table(params)
    cell = pred * (m.shape[1] * m.shape[2]) + lut_cells(distance_m, angle_deg, params)
    return m.reshape(-1)[cell]  # one flat gather (cheaper than 3-D advanced indexing)


def distance_weights(pred, distance_m, angle_deg, params: WeightingParams) -> torch.Tensor:
    d = distance_m.clamp_min(params.distance_ref_m)
    return ((params.distance_ref_m / d) ** 2).clamp_min(params.min_weight)


def incidence_weights(pred, distance_m, angle_deg, params: WeightingParams) -> torch.Tensor:
    return torch.cos(torch.deg2rad(angle_deg)).clamp_min(params.min_weight)


def sweet_spot_weights(pred, distance_m, angle_deg, params: WeightingParams) -> torch.Tensor:
    x = (distance_m - params.sweet_spot_m) / params.sweet_spot_halfwidth_m
    return (1.0 - x * x).clamp_min(params.min_weight)


def resolve(name: str, fusion: str) -> str:
    """A weighting name with ``auto`` resolved by the fusion strategy ``fusion``
    (``mapping.registry.FUSIONS``): ``lut`` for a gated one (glfs: its GLFS table), ``none``
    otherwise; a ValueError names the valid choices (``auto`` and ``mapping.registry.WEIGHTINGS``)."""
    if check_weighting(name) == AUTO_WEIGHTING:
        return "lut" if FUSIONS.get(fusion).gated else "none"
    return name


def needs_geometry(name: str) -> bool:
    """Whether weighting ``name`` uses the camera distance / incidence angle."""
    return check_weighting(name) not in (AUTO_WEIGHTING, "none")   # auto before it is resolved: none


def sample_weights(name: str, pred: torch.Tensor, distance_m: torch.Tensor, angle_deg: torch.Tensor,
                   params: WeightingParams | None = None) -> torch.Tensor:
    """Weights (...) of observations with predicted class ``pred`` (..., int64, argmax of the
    *scaled* logits; only ``lut`` uses it, others accept None), camera distance
    ``distance_m`` (...) metres and incidence angle ``angle_deg`` (...) degrees in [0, 90]."""
    return WEIGHTINGS.get(name)(pred, distance_m, angle_deg, params or WeightingParams())
