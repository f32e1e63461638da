"""Target prediction (PEANUT, Zhai & Wang, ICCV 2023): from the agent's partial 2D semantic map,
the probability that an unseen instance of each goal category lies at each cell.

Input (``map_input``): a square window of the map centred on the agent, ``window_cells`` cells
of ``cell_m`` (the 5 cm map pooled ``cell_m / map cell`` times: 128 x 0.2 m = 25.6 m by
default, PEANUT: 720 x 5 cm = 36 m), channels in ``INPUT_CHANNELS`` order then one per class of
the map (the segmenter's, confidences in [0, 1]). Obstacles, the agent's cell, the visited
cells and the confidences are max-pooled (any evidence in the coarse cell), "explored" is the
explored fraction of the coarse cell. Output: one logit map per goal category at 1/4 of the
window (stride 4), upsampled bilinearly; sigmoid = probability (PEANUT: BCE, sigmoid).

Use (``predicted_goal``, PEANUT's agent): value = probability x exp(-geodesic distance /
``distance_m``) over cells not yet explored (and not excluded) within ``near_m`` of explored
ones (where the network was trained: ``eval.prediction.train``), the long-term goal its argmax
(PEANUT: dist_weight_temperature 500 cm, the call every update_goal_freq = 10 steps).

Weights file (``torch.save`` of a plain dict, ``weights_only`` loading): format, spec
(``PredictorSpec``), state_dict, meta (command, seed, data, wall time, held-out metrics).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from calnav.agent.segmenters.base import class_list
from calnav.agent.segmenters.network import DSBlock, Encoder, conv_bn, fuse_batchnorm

PREDICTOR_FORMAT = 1
INPUT_CHANNELS: tuple[str, ...] = ("obstacle", "explored", "agent", "visited")  # then the map's classes
WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
DEFAULT_PREDICTOR = WEIGHTS_DIR / "predictor.pt"
MIN_VALUE = 1e-4   # below this best value the prediction says nothing: frontier exploration decides


@dataclass(frozen=True)
class PredictorSpec:
    """What the network reads and predicts. class_names: the map's classes (input channels
    after INPUT_CHANNELS); goal_categories: output channels; cell_m: coarse cell, metres;
    window_cells: input side, coarse cells (a multiple of 16)."""

    class_names: tuple[str, ...]
    goal_categories: tuple[str, ...]
    cell_m: float = 0.2
    window_cells: int = 128
    near_m: float = 4.0      # trained and used on unexplored cells within this of explored ones (square), metres
    stem: int = 24
    stages: tuple[tuple[int, int], ...] = ((32, 1), (64, 2), (96, 2))
    width: int = 48

    @property
    def in_channels(self) -> int:
        return len(INPUT_CHANNELS) + len(self.class_names)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "PredictorSpec":
        d = dict(d)
        d["class_names"] = class_list(d["class_names"], "predictor spec")
        d["goal_categories"] = class_list(d["goal_categories"], "predictor spec goal_categories")
        d["stages"] = tuple(tuple(int(v) for v in s) for s in d["stages"])
        return cls(**d)


class PredictorNet(nn.Module):
    """Map channels (B, C, S, S) -> goal logits (B, G, S, S): the segmenter's depthwise-separable
    encoder (strides 2, 4, 8, 16 with the default stages) and an FPN-style decoder to stride 4
    with the global context of the deepest level, upsampled bilinearly."""

    def __init__(self, spec: PredictorSpec):
        super().__init__()
        self.spec = spec
        self.encoder = Encoder(spec.in_channels, spec.stem, spec.stages)
        d = spec.width
        self.laterals = nn.ModuleList(conv_bn(c, d, 1, act=False) for c in self.encoder.channels)
        self.context = conv_bn(self.encoder.channels[-1], d, 1)
        self.smooth = DSBlock(d, d, 1)
        self.head = nn.Conv2d(d, len(spec.goal_categories), 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        size = x.shape[-2:]
        x = self.encoder.stem(x)
        feats = []
        for stage in self.encoder.stages:
            x = stage(x)
            feats.append(x)
        top = self.laterals[-1](feats[-1]) + self.context(feats[-1].mean(dim=(2, 3), keepdim=True))
        for lat, f in zip(reversed(self.laterals[:-1]), reversed(feats[:-1])):
            top = lat(f) + F.interpolate(top, size=f.shape[-2:], mode="bilinear", align_corners=False)
        return F.interpolate(self.head(self.smooth(F.relu(top))), size=size, mode="bilinear", align_corners=False)


def near_explored(explored: np.ndarray, cells: int) -> np.ndarray:
    """Cells within ``cells`` (Chebyshev distance, a square) of an explored cell: (n0, n1) bool."""
    import cv2

    return cv2.dilate(explored.astype(np.uint8), np.ones((2 * cells + 1, 2 * cells + 1), np.uint8)).astype(bool)


def pool_factor(spec: PredictorSpec, map_cell_m: float) -> int:
    """Map cells per coarse cell; ValueError unless cell_m is a whole multiple of the map cell."""
    f = spec.cell_m / map_cell_m
    if abs(f - round(f)) > 1e-6 or round(f) < 1:
        raise ValueError(f"the predictor's cell ({spec.cell_m} m) is not a whole multiple of agent.cell_m "
                         f"({map_cell_m} m): train it for this map")
    return int(round(f))


def crop_origin(agent_rc: tuple[int, int], spec: PredictorSpec, factor: int) -> tuple[int, int]:
    """Map cell (row, col) of the input window's corner: the window is centred on the agent."""
    half = spec.window_cells * factor // 2
    return agent_rc[0] - half, agent_rc[1] - half


def _crop(a: np.ndarray, r0: int, c0: int, size: tuple[int, int]) -> np.ndarray:
    """a (C, n, n) cropped to rows [r0, r0 + size[0]) and cols [c0, c0 + size[1]), zero outside
    the map (a view when the crop lies inside)."""
    n0, n1 = a.shape[1:]
    if r0 >= 0 and c0 >= 0 and r0 + size[0] <= n0 and c0 + size[1] <= n1:
        return a[:, r0:r0 + size[0], c0:c0 + size[1]]
    out = np.zeros((a.shape[0], *size), a.dtype)
    rs, cs = max(r0, 0), max(c0, 0)
    re, ce = min(r0 + size[0], n0), min(c0 + size[1], n1)
    if rs < re and cs < ce:
        out[:, rs - r0:re - r0, cs - c0:ce - c0] = a[:, rs:re, cs:ce]
    return out


def map_input(channels: dict[str, np.ndarray], semantic: np.ndarray, agent_rc: tuple[int, int],
              spec: PredictorSpec, map_cell_m: float, region: tuple[slice, slice] | None = None) -> np.ndarray:
    """The network input (C, S, S) float32 in [0, 1] around ``agent_rc`` (map row, col).
    channels: {'obstacle', 'explored', 'visited'} (n, n) bool maps; semantic (K, n, n) float32
    confidences of ``spec.class_names``; region: (row slice, col slice) outside which every map
    is empty (the explored bounding box), so only it is pooled (None: the whole map)."""
    if semantic.shape[0] != len(spec.class_names):
        raise ValueError(f"the map has {semantic.shape[0]} classes, the predictor reads {len(spec.class_names)}")
    f = pool_factor(spec, map_cell_m)
    s = spec.window_cells
    r0, c0 = crop_origin(agent_rc, spec, f)
    n0, n1 = semantic.shape[1:]
    rows, cols = region or (slice(0, n0), slice(0, n1))
    # the coarse cells [i0, i1) x [j0, j1) of the window that overlap the region
    i0, i1 = max(0, (rows.start - r0) // f), min(s, -(-(rows.stop - r0) // f))
    j0, j1 = max(0, (cols.start - c0) // f), min(s, -(-(cols.stop - c0) // f))
    out = np.zeros((spec.in_channels, s, s), np.float32)
    out[2, (agent_rc[0] - r0) // f, (agent_rc[1] - c0) // f] = 1.0   # the agent's cell
    if i0 >= i1 or j0 >= j1:
        return out
    h, w = i1 - i0, j1 - j0
    rs, cs = r0 + i0 * f, c0 + j0 * f

    def pooled(a: np.ndarray, how: str) -> np.ndarray:
        t = torch.from_numpy(np.ascontiguousarray(_crop(a, rs, cs, (h * f, w * f)), np.float32))
        return (F.max_pool2d if how == "max" else F.avg_pool2d)(t[None], f)[0].numpy()

    out[0, i0:i1, j0:j1] = pooled(channels["obstacle"][None], "max")[0]
    out[1, i0:i1, j0:j1] = pooled(channels["explored"][None], "mean")[0]
    out[3, i0:i1, j0:j1] = pooled(channels["visited"][None], "max")[0]
    out[4:, i0:i1, j0:j1] = pooled(semantic, "max")
    return out


def load_predictor_weights(path: Path | str) -> dict:
    """The weight dict of ``path``; FileNotFoundError / ValueError naming the file."""
    from calnav.common.weights import load_weight_dict

    path = Path(path)
    data = load_weight_dict(path, "predictor", PREDICTOR_FORMAT, f"calnav train-predictor --data DIR --output {path}")
    try:
        spec = PredictorSpec.from_dict(data["spec"])
        PredictorNet(spec).load_state_dict({k: v.float() for k, v in data["state_dict"].items()})
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ValueError(f"damaged predictor weights {path}: {first}") from None
    return data


def check_predictor(path: Path | str, class_names: tuple[str, ...], goal_categories: tuple[str, ...],
                    map_cell_m: float) -> PredictorSpec:
    """The spec of the predictor at ``path`` if it reads a map of ``class_names`` at
    ``map_cell_m`` and predicts every goal category; ValueError naming the mismatch."""
    spec = PredictorSpec.from_dict(load_predictor_weights(path)["spec"])
    if tuple(spec.class_names) != tuple(class_names):
        raise ValueError(f"predictor {path} reads a map of the classes {', '.join(spec.class_names)}; this agent's "
                         f"segmenter has {', '.join(class_names)}: train a predictor on its maps")
    missing = [g for g in goal_categories if g not in spec.goal_categories]
    if missing:
        raise ValueError(f"predictor {path} predicts no {', '.join(missing)} (it predicts "
                         f"{', '.join(spec.goal_categories)})")
    pool_factor(spec, map_cell_m)
    return spec


def save_predictor(net: PredictorNet, path: Path | str, meta: dict) -> Path:
    """Write ``net`` (fp16 tensors) atomically; returns the path."""
    from calnav.common.atomic import atomic_path

    state = {k: (v.detach().cpu().half() if v.is_floating_point() else v.detach().cpu())
             for k, v in net.state_dict().items()}
    with atomic_path(path) as tmp:
        torch.save({"format": PREDICTOR_FORMAT, "spec": net.spec.to_dict(), "state_dict": state, "meta": dict(meta)}, tmp)
    return Path(path)


class Predictor:
    """The trained network for inference: ``probabilities(channels, semantic, agent_rc, map_cell_m)``
    -> ((G, S*f, S*f) float32 probabilities on the map's cells, (row, col) of its corner)."""

    def __init__(self, path: Path | str, threads: int = 0):
        data = load_predictor_weights(path)
        self.path = Path(path)
        self.spec = PredictorSpec.from_dict(data["spec"])
        self.meta = dict(data.get("meta", {}))
        self.net = PredictorNet(self.spec)
        self.net.load_state_dict({k: v.float() for k, v in data["state_dict"].items()})
        fuse_batchnorm(self.net.eval())
        if threads > 0:
            torch.set_num_threads(threads)

    @torch.inference_mode()
    def probabilities(self, channels: dict[str, np.ndarray], semantic: np.ndarray, agent_rc: tuple[int, int],
                      map_cell_m: float, goal: str, region: tuple[slice, slice] | None = None
                      ) -> tuple[np.ndarray, tuple[int, int]]:
        """Probability (side, side) float32 of goal category ``goal`` on map cells (side = window
        cells x pool factor) and the map (row, col) of the window's corner (``map_input`` for
        ``region``)."""
        f = pool_factor(self.spec, map_cell_m)
        x = torch.from_numpy(map_input(channels, semantic, agent_rc, self.spec, map_cell_m, region))[None]
        g = self.spec.goal_categories.index(goal)
        p = torch.sigmoid(self.net(x)[0, g]).numpy()
        return np.repeat(np.repeat(p, f, axis=0), f, axis=1), crop_origin(agent_rc, self.spec, f)


def predicted_goal(prob: np.ndarray, corner: tuple[int, int], window: tuple[slice, slice], distance_cells: np.ndarray,
                   candidates: np.ndarray, distance_m: float, cell_m: float) -> tuple[tuple[int, int], float] | None:
    """PEANUT's long-term goal in window coordinates and its value: argmax of probability x
    exp(-geodesic distance / distance_m) over ``candidates`` (window (h, w) bool: unexplored,
    reachable, not excluded). prob (side, side) on map cells from map cell ``corner``;
    distance_cells (h, w) geodesic distance from the agent in cells (inf = unreachable).
    None when no candidate reaches MIN_VALUE."""
    h, w = candidates.shape
    local = np.zeros((h, w), np.float32)   # the prediction on the window's cells (0 outside the crop)
    r0, c0 = corner[0] - window[0].start, corner[1] - window[1].start
    rs, cs, re, ce = max(r0, 0), max(c0, 0), min(r0 + prob.shape[0], h), min(c0 + prob.shape[1], w)
    if rs < re and cs < ce:
        local[rs:re, cs:ce] = prob[rs - r0:re - r0, cs - c0:ce - c0]
    ok = candidates & np.isfinite(distance_cells)
    if not ok.any():
        return None
    value = np.where(ok, local * np.exp(-np.where(ok, distance_cells, 0.0) * cell_m / distance_m), 0.0)
    best = int(np.argmax(value))
    if not value.flat[best] >= MIN_VALUE or not math.isfinite(float(value.flat[best])):
        return None
    return (best // w, best % w), float(value.flat[best])
