"""Training the Generalized Learned Fusion Strategy (paper Sec. V-D: theta and the loss).

theta = (tau (K) per-class temperatures, M (K, n_dist, n_angle) sample-weight table, G and eps
gates). Unlike the authors' release, which fixed G = eps = 0, calnav learns the gates too
(projected onto [0, 1] after every step; they start at the authors' fixed values).

Loss per mini-batch of voxels (all their cached observations fused with ``fuse_flat``):
class-weighted NLL of the fused probabilities (weights (1 / ln(1.02 + frequency)), normalised to
mean 1, the authors' inverse-log-frequency weighting) + ``eta`` * mDECE (Bohdal et al.; t_a =
100, t_b = 0.01). The NLL's class weighting is a choice (``class_weighting``: the authors'
``log_inverse_frequency`` or ``none``). Adam, optional gradient-norm clipping (authors: 1).
tau is optimised as log tau (positive by construction; initial value ``init_tau``, authors 0.4);
M is clipped at 0 after every step. Fixed gates (the authors' release: G = eps = 0) are
``learn_gates: false`` with ``init_g = init_eps = 0``.

Model selection (``mapping.calibration.selection``): ``val_per_epoch`` times per epoch (authors:
3) the fused calibration-*validation* voxels are scored (loss, hard mIoU, hard mECE); the rule
``selection`` decides which checkpoint is kept (``val_loss``: lowest loss, calnav's default;
``val_miou``: highest mIoU, the authors'; ``constrained``: lowest mECE among checkpoints within
``miou_tolerance_points`` of the initial parameters' mIoU) and stops training after
``patience`` checks without improvement.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from calnav.mapping import metrics
from calnav.mapping.calibration.flat_obs import FlatObservations
from calnav.mapping.calibration.glfs_config import CLASS_WEIGHTINGS, LOG_TAU_LIMIT, GLFSTrainConfig
from calnav.mapping.calibration.selection import CheckpointSelector, ValidationScore
from calnav.mapping.fusion import fuse_flat
from calnav.mapping.glfs import GLFSParams
from calnav.mapping.calibration.metrics_torch import mdece
from calnav.mapping.weighting import WeightingParams, sample_weights

PROB_FLOOR = 1e-6   # log(max(p, floor)) in the NLL: a hard zero probability must not give inf


def class_weights(frequency: np.ndarray, weighting: str = "log_inverse_frequency") -> torch.Tensor:
    """(K,) NLL class weights, 0 for absent classes: ``log_inverse_frequency`` 1 / ln(1.02 + f)
    normalised to mean 1 over present classes, or ``none`` (1 for every present class)."""
    if weighting not in CLASS_WEIGHTINGS:
        raise ValueError(f"unknown class weighting {weighting!r}; valid: {', '.join(CLASS_WEIGHTINGS)}")
    present = np.asarray(frequency) > 0
    if weighting == "none":
        return torch.as_tensor(present, dtype=torch.float32)
    w = 1.0 / np.log(1.02 + np.asarray(frequency, dtype=np.float64))
    w = w / w[present].mean() if present.any() else w
    return torch.as_tensor(np.where(present, w, 0.0), dtype=torch.float32)


class GLFSModel(torch.nn.Module):
    """The learnable theta; ``forward(obs)`` -> fused probabilities (N, K)."""

    def __init__(self, num_classes: int, cfg: GLFSTrainConfig):
        super().__init__()
        n_d, n_a = len(cfg.distance_edges) - 1, len(cfg.angle_edges_deg) - 1
        self.cfg = cfg
        self.log_tau = torch.nn.Parameter(torch.full((num_classes,), float(np.log(cfg.init_tau))))
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
        self.log_tau.clamp_(-LOG_TAU_LIMIT, LOG_TAU_LIMIT)

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
    """Per-epoch mean training loss; per validation check (the first: the initial parameters)
    its fractional epoch, loss, hard mIoU and hard mECE; the kept check and whether patience
    ran out."""

    train_loss: list[float] = field(default_factory=list)
    val_epoch: list[float] = field(default_factory=list)
    val_loss: list[float] = field(default_factory=list)
    val_miou: list[float] = field(default_factory=list)
    val_mece: list[float] = field(default_factory=list)
    best_check: int = 0
    stopped_early: bool = False

    @property
    def best_epoch(self) -> float:
        """Fractional epoch of the kept checkpoint (0 = the initial parameters)."""
        return self.val_epoch[self.best_check]

    def to_dict(self) -> dict:
        return {"train_loss": self.train_loss, "val_epoch": self.val_epoch, "val_loss": self.val_loss,
                "val_miou": self.val_miou, "val_mece": self.val_mece, "best_check": self.best_check,
                "best_epoch": self.best_epoch, "stopped_early": self.stopped_early}


@torch.no_grad()
def validation_score(model: GLFSModel, val: FlatObservations, weights: torch.Tensor, eta: float) -> ValidationScore:
    """Loss, hard mIoU (calnav's convention) and hard mECE of the map fused from ``val``."""
    probs = model(val)
    stats = metrics.CalibrationStats(val.num_classes).update(probs.numpy(), val.labels.numpy())
    return ValidationScore(float(glfs_loss(probs, val.labels, weights, eta)), stats.miou(), stats.mece())


def _check_points(n_batches: int, per_epoch: int) -> set[int]:
    """Batch indices (0-based) after which an epoch of ``n_batches`` is validated: ``per_epoch``
    evenly spaced points, the last one at the epoch's end."""
    return {max(int(round(n_batches * (i + 1) / per_epoch)) - 1, 0) for i in range(per_epoch)}


def train_glfs(train: FlatObservations, val: FlatObservations, cfg: GLFSTrainConfig | None = None,
               class_names: tuple[str, ...] = (), progress: bool = True) -> tuple[GLFSParams, TrainHistory]:
    """Fit theta on ``train`` voxels, validating on ``val`` voxels ``cfg.val_per_epoch`` times an
    epoch; returns the parameters kept by ``cfg.selection`` and the history. Seeded by ``cfg.seed``."""
    from tqdm import tqdm

    cfg = cfg or GLFSTrainConfig()
    if train.num_classes != val.num_classes:
        raise ValueError(f"train and val observations disagree on K ({train.num_classes} vs {val.num_classes})")
    if class_names and len(class_names) != train.num_classes:
        raise ValueError(f"{len(class_names)} class names for K = {train.num_classes}")
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    model = GLFSModel(train.num_classes, cfg)
    weights = class_weights(train.class_frequency(), cfg.class_weighting)
    trainable = [p for p in model.parameters() if p.requires_grad]
    opt = torch.optim.Adam(trainable, lr=cfg.lr)
    selector = CheckpointSelector(cfg.selection, cfg.patience, cfg.miou_tolerance_points)
    hist = TrainHistory()

    def check(epoch: float) -> None:
        s = validation_score(model, val, weights, cfg.eta)
        hist.val_epoch.append(epoch)
        hist.val_loss.append(s.loss)
        hist.val_miou.append(s.miou)
        hist.val_mece.append(s.mece)
        if selector.update(s):
            nonlocal best_state
            best_state = {k: t.clone() for k, t in model.state_dict().items()}

    best_state: dict = {}
    check(0.0)
    n_batches = -(-train.num_voxels // cfg.batch_voxels)
    checks = _check_points(n_batches, cfg.val_per_epoch)
    bar = tqdm(range(cfg.epochs), desc="train glfs", unit="epoch", disable=not progress)
    for epoch in bar:
        losses = []
        for b, batch in enumerate(train.batches(cfg.batch_voxels, rng)):
            opt.zero_grad()
            loss = glfs_loss(model(batch), batch.labels, weights, cfg.eta)
            loss.backward()
            if cfg.grad_clip > 0:
                torch.nn.utils.clip_grad_norm_(trainable, cfg.grad_clip)
            opt.step()
            model.project()
            losses.append(float(loss.detach()))
            if b in checks:
                check(epoch + (b + 1) / n_batches)
                if selector.stop:
                    break
        hist.train_loss.append(float(np.mean(losses)))
        bar.set_postfix(train=f"{hist.train_loss[-1]:.4f}", val=f"{hist.val_loss[-1]:.4f}",
                        miou=f"{hist.val_miou[-1]:.3f}", mece=f"{hist.val_mece[-1]:.3f}")
        if selector.stop:
            hist.stopped_early = True
            break
    hist.best_check = selector.best_index
    model.load_state_dict(best_state)
    return model.params(tuple(class_names)), hist
