"""Fitting logit temperatures (paper Sec. V-C; the paper's search set-up: Sec. VI-B).

- ``fit_temperature_2d``: classic temperature scaling of the *segmenter* (Guo et al.): one tau
  minimising the pixel negative log-likelihood, by L-BFGS on log tau (the NLL is smooth and
  unimodal in log tau, so a gradient method is the right tool).
- ``fit_temperature_3d``: one tau minimising the voxel mECE of the *fused* map for a given
  fusion strategy. mECE is piecewise constant in tau (binned), so gradients are useless; the
  paper used Bayesian optimisation. calnav uses a robust derivative-free search instead: a
  log-spaced grid over [0.01, 200] (the paper's range), then golden-section refinement on
  log tau between the best grid point's neighbours. Each evaluation re-fuses the cached
  observations (``fuse_flat``, a fraction of a second), never re-maps.
- ``fit_vector_3d``: one tau per class, by cyclic coordinate descent from the best scalar:
  each class's log tau gets a golden-section search in a bracket around its current value,
  accepted only if the map's mECE improves. Derivative-free for the same reason; it also
  works for ``histogram``, whose argmax votes only move when the temperatures differ by class.

A scalar temperature does not change an argmax, so ``histogram`` is invariant to it: the
search sees a flat objective and keeps tau = 1 (``FitResult.flat``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch

from calnav.mapping import metrics
from calnav.mapping.calibration.flat_obs import FlatObservations
from calnav.mapping.fusion import fuse_flat, get_strategy

TAU_RANGE = (0.01, 200.0)     # the authors' temperature search range
GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0
OBJECTIVES: dict[str, Callable] = {"mece": metrics.mece, "ece": metrics.ece, "tl_ece": metrics.tl_ece,
                                   "brier": metrics.brier}


@dataclass
class FitResult:
    """temperature: float (scalar) or (K,) array; objective: its value; evaluations: how many
    fusions were scored; flat: the objective did not depend on the temperature (kept 1)."""

    temperature: float | np.ndarray
    objective: float
    evaluations: int
    flat: bool = False
    trace: list[tuple[float, float]] = field(default_factory=list)


def fit_temperature_2d(logits: np.ndarray | torch.Tensor, labels: np.ndarray | torch.Tensor,
                       max_iter: int = 100) -> FitResult:
    """tau minimising the NLL of softmax(logits / tau). logits (n, K); labels (n,) class ids
    (negative labels are void and dropped)."""
    z = torch.as_tensor(np.asarray(logits, dtype=np.float32))
    y = torch.as_tensor(np.asarray(labels)).long()
    if z.ndim != 2 or y.shape != (z.shape[0],):
        raise ValueError(f"need logits (n, K) and labels (n,), got {tuple(z.shape)} and {tuple(y.shape)}")
    keep = y >= 0
    z, y = z[keep], y[keep]
    if len(y) == 0:
        raise ValueError("no labelled pixels to fit a temperature on")
    if not bool(torch.isfinite(z).all()):
        raise ValueError("logits contain NaN or inf")
    log_tau = torch.zeros((), requires_grad=True)
    opt = torch.optim.LBFGS([log_tau], lr=0.5, max_iter=max_iter, line_search_fn="strong_wolfe")

    def closure():
        opt.zero_grad()
        loss = torch.nn.functional.cross_entropy(z / log_tau.exp(), y)
        loss.backward()
        return loss

    opt.step(closure)
    lo, hi = (math.log(v) for v in TAU_RANGE)
    tau = float(math.exp(min(max(float(log_tau.detach()), lo), hi)))
    with torch.no_grad():
        nll = float(torch.nn.functional.cross_entropy(z / tau, y))
    # LBFGS keeps its counters in the (public) per-parameter state of its first parameter
    return FitResult(tau, nll, opt.state[log_tau].get("func_evals", 0))


class MapObjective:
    """Calibration error of the map fused from ``obs`` with ``strategy`` at a temperature;
    memoised (the searches revisit points)."""

    def __init__(self, obs: FlatObservations, strategy: str, objective: str = "mece"):
        if objective not in OBJECTIVES:
            raise ValueError(f"unknown objective {objective!r}; valid: {', '.join(OBJECTIVES)}")
        self.obs, self.strategy, self.metric = obs, get_strategy(strategy), OBJECTIVES[objective]
        if self.strategy.gated:
            raise ValueError("3D temperature scaling applies to the fixed strategies; glfs learns its own tau (train_glfs)")
        self.labels = obs.labels.numpy()
        self._memo: dict[bytes, float] = {}

    def probs(self, temperature) -> np.ndarray:
        with torch.no_grad():
            return fuse_flat(self.obs.logits, self.obs.voxel, self.obs.num_voxels, self.strategy,
                             weights=self.obs.weight, temperature=temperature).numpy()

    def __call__(self, temperature) -> float:
        t = np.asarray(temperature, dtype=np.float64)
        key = t.round(6).tobytes()
        if key not in self._memo:
            self._memo[key] = float(self.metric(self.probs(t.astype(np.float32)), self.labels))
        return self._memo[key]

    @property
    def evaluations(self) -> int:
        return len(self._memo)


def _golden(f: Callable[[float], float], lo: float, hi: float, iters: int) -> tuple[float, float]:
    """Golden-section minimisation of f on [lo, hi]: (argmin, min) among the points evaluated."""
    a, b = lo, hi
    c, d = b - GOLDEN * (b - a), a + GOLDEN * (b - a)
    fc, fd = f(c), f(d)
    best = min((fc, c), (fd, d))
    for _ in range(iters):
        if fc <= fd:
            b, d, fd = d, c, fc
            c = b - GOLDEN * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + GOLDEN * (b - a)
            fd = f(d)
        best = min(best, (fc, c), (fd, d))
    return best[1], best[0]


def fit_temperature_3d(obs: FlatObservations, strategy: str, objective: str = "mece", grid_points: int = 21,
                       refine_iters: int = 10, tau_range: tuple[float, float] = TAU_RANGE) -> FitResult:
    """Scalar tau minimising the fused map's ``objective`` (log grid + golden-section)."""
    f = MapObjective(obs, strategy, objective)
    if grid_points < 3:
        raise ValueError(f"grid_points must be >= 3, got {grid_points}")
    logs = np.linspace(math.log(tau_range[0]), math.log(tau_range[1]), grid_points)
    values = np.array([f(math.exp(x)) for x in logs])
    trace = [(float(math.exp(x)), float(v)) for x, v in zip(logs, values)]
    if np.ptp(values) < 1e-9:
        return FitResult(1.0, f(1.0), f.evaluations, flat=True, trace=trace)
    i = int(np.argmin(values))
    lo, hi = logs[max(i - 1, 0)], logs[min(i + 1, grid_points - 1)]
    x, v = _golden(lambda x: f(math.exp(x)), lo, hi, refine_iters)
    if values[i] <= v:
        x, v = logs[i], float(values[i])
    return FitResult(float(math.exp(x)), float(v), f.evaluations, trace=trace)


def fit_vector_3d(obs: FlatObservations, strategy: str, init: float | np.ndarray = 1.0, objective: str = "mece",
                  sweeps: int = 2, bracket: float = 1.5, refine_iters: int = 6,
                  tau_range: tuple[float, float] = TAU_RANGE) -> FitResult:
    """Per-class tau (K,) minimising the fused map's ``objective`` by cyclic coordinate descent
    in log space, starting from ``init`` (typically the best scalar). ``bracket``: half-width of
    each class's search interval in log tau (1.5 = a factor e^1.5 ~ 4.5 either way)."""
    f = MapObjective(obs, strategy, objective)
    k = obs.num_classes
    log_tau = np.log(np.broadcast_to(np.asarray(init, dtype=np.float64), (k,)).copy())
    lo_lim, hi_lim = math.log(tau_range[0]), math.log(tau_range[1])
    best = f(np.exp(log_tau))
    trace = [(float("nan"), best)]
    for _ in range(sweeps):
        improved = False
        for c in range(k):
            def along(x: float, c=c) -> float:
                t = log_tau.copy()
                t[c] = x
                return f(np.exp(t))
            lo, hi = max(log_tau[c] - bracket, lo_lim), min(log_tau[c] + bracket, hi_lim)
            x, v = _golden(along, lo, hi, refine_iters)
            if v < best - 1e-6:
                log_tau[c], best, improved = x, v, True
                trace.append((float(c), best))
        if not improved:
            break
    return FitResult(np.exp(log_tau).astype(np.float32), float(best), f.evaluations, trace=trace)
