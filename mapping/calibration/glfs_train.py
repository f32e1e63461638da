"""Training the Generalized Learned Fusion Strategy (paper Sec. V-D: theta and the loss).

theta = (tau (K) per-class temperatures, M (K, n_dist, n_angle) sample-weight table, G and eps
gates). Unlike the authors' release, which fixed G = eps = 0, calnav learns the gates too
(projected onto [0, 1] after every step; they start at the authors' fixed values).

Loss per mini-batch of voxels (all their cached observations fused with ``fuse_flat``):
class-weighted NLL of the fused probabilities (weights (1 / ln(1.02 + frequency)), normalised to
mean 1, the authors' inverse-log-frequency weighting) + ``eta`` * mDECE (Bohdal et al.; t_a =
100, t_b = 0.01). Adam. tau is optimised as log tau (positive by construction); M is clipped at
0 after every step. Early stopping: after each epoch the loss on calibration-*validation*
voxels is computed, the best parameters are kept, and training stops after ``patience`` epochs
without improvement. (The authors stopped on validation mIoU; the validation loss is used here
because it scores calibration and accuracy together, which is what the parameters are for.)
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from mapping.calibration.flat_obs import FlatObservations
from mapping.fusion import fuse_flat
from mapping.glfs import GLFSParams
from mapping.calibration.metrics_torch import mdece
from mapping.weighting import ANGLE_EDGES_DEG, DISTANCE_EDGES_M, WeightingParams, sample_weights

PROB_FLOOR = 1e-6   # log(max(p, floor)) in the NLL: a hard zero probability must not give inf


@dataclass
class GLFSTrainConfig:
    epochs: int = 30               # maximum passes over the calibration-train voxels
    batch_voxels: int = 4096       # voxels per mini-batch (with all their observations)
    lr: float = 0.05               # Adam learning rate (log tau, M and the gates)
    eta: float = 0.5               # weight of mDECE in the loss (authors: 0.5)
    patience: int = 4              # epochs without validation improvement before stopping
    learn_gates: bool = True       # learn G and eps (False: keep them at their initial values)
    init_g: float = 0.0            # initial G (authors' fixed value)
    init_eps: float = 0.0          # initial eps (authors' fixed value)
    seed: int = 0                  # mini-batch order
    distance_edges: tuple[float, ...] = DISTANCE_EDGES_M    # LUT distance bin edges, metres
    angle_edges_deg: tuple[float, ...] = ANGLE_EDGES_DEG     # LUT incidence-angle bin edges, degrees

    def __post_init__(self) -> None:
        if self.epochs < 1 or self.batch_voxels < 1 or self.patience < 1:
            raise ValueError("glfs training: epochs, batch_voxels and patience must be >= 1")
        if not self.lr > 0 or self.eta < 0:
            raise ValueError(f"glfs training: need lr > 0 and eta >= 0, got {self.lr}, {self.eta}")
        if not (0 <= self.init_g <= 1 and 0 <= self.init_eps <= 1):
            raise ValueError("glfs training: init_g and init_eps must be in [0, 1]")


def class_weights(frequency: np.ndarray) -> torch.Tensor:
    """(K,) inverse-log-frequency weights 1 / ln(1.02 + f), normalised to mean 1 over present classes."""
    w = 1.0 / np.log(1.02 + np.asarray(frequency, dtype=np.float64))
    present = np.asarray(frequency) > 0
    w = w / w[present].mean() if present.any() else w
    return torch.as_tensor(np.where(present, w, 0.0), dtype=torch.float32)


class GLFSModel(torch.nn.Module):
    """The learnable theta; ``forward(obs)`` -> fused probabilities (N, K)."""

    def __init__(self, num_classes: int, cfg: GLFSTrainConfig):
        super().__init__()
        n_d, n_a = len(cfg.distance_edges) - 1, len(cfg.angle_edges_deg) - 1
        self.cfg = cfg
        self.log_tau = torch.nn.Parameter(torch.zeros(num_classes))
        self.M = torch.nn.Parameter(torch.ones(num_classes, n_d, n_a))
        self.g = torch.nn.Parameter(torch.tensor(float(cfg.init_g)), requires_grad=cfg.learn_gates)
        self.eps = torch.nn.Parameter(torch.tensor(float(cfg.init_eps)), requires_grad=cfg.learn_gates)

    @classmethod
    def from_params(cls, params: GLFSParams) -> "GLFSModel":
        """A model holding fitted ``params`` (to fuse observations with them)."""
        cfg = GLFSTrainConfig(distance_edges=params.distance_edges, angle_edges_deg=params.angle_edges_deg)
        model = cls(params.num_classes, cfg)
        with torch.no_grad():
            model.log_tau.copy_(torch.as_tensor(np.log(params.tau)))
            model.M.copy_(torch.as_tensor(params.M))
            model.g.fill_(params.g)
            model.eps.fill_(params.eps)
        return model

    def forward(self, obs: FlatObservations) -> torch.Tensor:
        tau = self.log_tau.exp()
        with torch.no_grad():
            pred = (obs.logits / tau).argmax(dim=1)
        params = WeightingParams(lut=self.M, distance_edges=self.cfg.distance_edges,
                                 angle_edges_deg=self.cfg.angle_edges_deg)
        w = sample_weights("lut", pred, obs.distance_m, obs.angle_deg, params) * obs.weight
        return fuse_flat(obs.logits, obs.voxel, obs.num_voxels, "glfs", weights=w, temperature=tau,
                         g=self.g, eps=self.eps)

    @torch.no_grad()
    def project(self) -> None:
        self.M.clamp_(min=0.0)
        self.g.clamp_(0.0, 1.0)
        self.eps.clamp_(0.0, 1.0)
        self.log_tau.clamp_(-6.0, 6.0)

    def params(self, class_names: tuple[str, ...] = ()) -> GLFSParams:
        return GLFSParams(tau=self.log_tau.detach().exp().numpy(), g=float(self.g.detach()), eps=float(self.eps.detach()),
                          M=self.M.detach().clamp(min=0).numpy(), distance_edges=self.cfg.distance_edges,
                          angle_edges_deg=self.cfg.angle_edges_deg, class_names=class_names)


def glfs_loss(probs: torch.Tensor, labels: torch.Tensor, weights: torch.Tensor, eta: float) -> torch.Tensor:
    """Class-weighted NLL + eta * mDECE of fused probs (N, K) against labels (N,)."""
    nll = torch.nn.functional.nll_loss(probs.clamp_min(PROB_FLOOR).log(), labels, weight=weights)
    return nll + eta * mdece(probs, labels) if eta > 0 else nll


@dataclass
class TrainHistory:
    train_loss: list[float] = field(default_factory=list)
    val_loss: list[float] = field(default_factory=list)
    best_epoch: int = -1
    stopped_early: bool = False


def train_glfs(train: FlatObservations, val: FlatObservations, cfg: GLFSTrainConfig | None = None,
               class_names: tuple[str, ...] = (), progress: bool = True) -> tuple[GLFSParams, TrainHistory]:
    """Fit theta on ``train`` voxels with early stopping on ``val`` voxels; returns the best
    parameters (by validation loss) and the loss history. Seeded by ``cfg.seed``."""
    from tqdm import tqdm

    cfg = cfg or GLFSTrainConfig()
    if train.num_classes != val.num_classes:
        raise ValueError(f"train and val observations disagree on K ({train.num_classes} vs {val.num_classes})")
    if class_names and len(class_names) != train.num_classes:
        raise ValueError(f"{len(class_names)} class names for K = {train.num_classes}")
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    model = GLFSModel(train.num_classes, cfg)
    weights = class_weights(train.class_frequency())
    opt = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=cfg.lr)
    hist = TrainHistory()
    with torch.no_grad():
        best_val = float(glfs_loss(model(val), val.labels, weights, cfg.eta))
    best_state = {k: v.clone() for k, v in model.state_dict().items()}
    hist.val_loss.append(best_val)
    stale = 0
    bar = tqdm(range(cfg.epochs), desc="train glfs", unit="epoch", disable=not progress)
    for epoch in bar:
        losses = []
        for batch in train.batches(cfg.batch_voxels, rng):
            opt.zero_grad()
            loss = glfs_loss(model(batch), batch.labels, weights, cfg.eta)
            loss.backward()
            opt.step()
            model.project()
            losses.append(float(loss.detach()))
        with torch.no_grad():
            v = float(glfs_loss(model(val), val.labels, weights, cfg.eta))
        hist.train_loss.append(float(np.mean(losses)))
        hist.val_loss.append(v)
        bar.set_postfix(train=f"{hist.train_loss[-1]:.4f}", val=f"{v:.4f}", g=f"{float(model.g.detach()):.2f}",
                        eps=f"{float(model.eps.detach()):.2f}")
        if v < best_val - 1e-5:
            best_val, stale, hist.best_epoch = v, 0, epoch
            best_state = {k: t.clone() for k, t in model.state_dict().items()}
        else:
            stale += 1
            if stale >= cfg.patience:
                hist.stopped_early = True
                break
    model.load_state_dict(best_state)
    return model.params(tuple(class_names)), hist
