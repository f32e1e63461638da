"""The GLFS training settings (the ``glfs`` config section), apart from the training itself
(``mapping.calibration.glfs_train``, which needs torch) so a config loads without torch."""
from __future__ import annotations

import math
from dataclasses import dataclass

from calnav.mapping.calibration.selection import SELECTION_RULES
from calnav.mapping.config import ANGLE_EDGES_DEG, DISTANCE_EDGES_M

CLASS_WEIGHTINGS: tuple[str, ...] = ("log_inverse_frequency", "none")
LOG_TAU_LIMIT = 6.0  # |log tau| <= 6: tau in [0.0025, 403]


@dataclass
class GLFSTrainConfig:
    epochs: int = 30               # maximum passes over the calibration-train voxels
    batch_voxels: int = 4096       # voxels per mini-batch (with all their observations)
    lr: float = 0.05               # Adam learning rate (log tau, M and the gates)
    eta: float = 0.5               # weight of mDECE in the loss (authors: 0.5)
    patience: int = 4              # validation checks without improvement before stopping
    learn_gates: bool = True       # learn G and eps (False: keep them at their initial values; authors: fixed 0)
    init_g: float = 0.0            # initial G (authors' fixed value)
    init_eps: float = 0.0          # initial eps (authors' fixed value)
    init_tau: float = 1.0          # initial per-class temperature (authors: 0.4)
    selection: str = "val_loss"    # kept checkpoint / early stopping: val_loss | val_miou (authors) | constrained
    miou_tolerance_points: float = 0.5  # constrained: admissible validation mIoU loss vs the initial params, mIoU points
    class_weighting: str = "log_inverse_frequency"  # NLL class weights: log_inverse_frequency (authors) | none
    val_per_epoch: int = 1         # validation checks per epoch (authors: 3)
    grad_clip: float = 0.0         # gradient-norm clip per step (0 = none; authors: 1)
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
        if not math.exp(-LOG_TAU_LIMIT) <= self.init_tau <= math.exp(LOG_TAU_LIMIT):
            raise ValueError(f"glfs training: init_tau must be in [{math.exp(-LOG_TAU_LIMIT):.4g}, "
                             f"{math.exp(LOG_TAU_LIMIT):.4g}], got {self.init_tau}")
        if self.selection not in SELECTION_RULES:
            raise ValueError(f"glfs training: unknown selection {self.selection!r}; valid: {', '.join(SELECTION_RULES)}")
        if self.class_weighting not in CLASS_WEIGHTINGS:
            raise ValueError(f"glfs training: unknown class_weighting {self.class_weighting!r}; "
                             f"valid: {', '.join(CLASS_WEIGHTINGS)}")
        if self.val_per_epoch < 1 or not self.miou_tolerance_points >= 0 or not self.grad_clip >= 0:
            raise ValueError("glfs training: need val_per_epoch >= 1, miou_tolerance_points >= 0 and grad_clip >= 0")
