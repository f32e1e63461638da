"""Model selection and early stopping for GLFS training: which validation checkpoint is kept,
and when training stops.

A checkpoint is scored on the calibration-validation voxels by ``ValidationScore`` (the
training loss, the hard mIoU in calnav's convention, and the hard mECE of the fused map). The
first score is always the *initial* parameters (before any step); the rules:

- ``val_loss``     keep the lowest validation loss (calnav's earlier rule: the ``learned`` variant);
- ``val_miou``     keep the highest validation mIoU (the authors' release);
- ``constrained``  keep the lowest validation mECE among checkpoints whose validation mIoU is
  at least the initial parameters' minus ``tolerance_points`` mIoU points (the initial
  checkpoint is always admissible, so a choice always exists).

A checkpoint counts as an improvement only when it beats the kept one by more than
``MIN_DELTA`` (loss, mIoU or mECE units); after ``patience`` consecutive checks without one,
training stops. The initial checkpoint never counts toward the patience.
"""
from __future__ import annotations

from dataclasses import dataclass, field

SELECTION_RULES: tuple[str, ...] = ("val_loss", "val_miou", "constrained")
MIN_DELTA = 1e-5        # smallest change that counts as an improvement (loss / mIoU / mECE units)
POINTS = 100.0          # mIoU points per unit mIoU


@dataclass(frozen=True)
class ValidationScore:
    """One validation check: loss (training objective), miou and mece (fractions, 0..1)."""

    loss: float
    miou: float
    mece: float


@dataclass
class CheckpointSelector:
    """Feed ``update`` one ``ValidationScore`` per check (the first: the initial parameters);
    it says whether to keep that checkpoint and sets ``stop`` when patience runs out."""

    rule: str
    patience: int
    tolerance_points: float = 0.5
    scores: list[ValidationScore] = field(default_factory=list)
    best_index: int = -1
    stale: int = 0
    stop: bool = False

    def __post_init__(self) -> None:
        if self.rule not in SELECTION_RULES:
            raise ValueError(f"unknown selection rule {self.rule!r}; valid: {', '.join(SELECTION_RULES)}")
        if self.patience < 1:
            raise ValueError(f"patience must be >= 1, got {self.patience}")
        if not self.tolerance_points >= 0:
            raise ValueError(f"tolerance_points must be >= 0 mIoU points, got {self.tolerance_points}")

    @property
    def best(self) -> ValidationScore:
        return self.scores[self.best_index]

    def admissible(self, s: ValidationScore) -> bool:
        """Whether ``s`` may be kept under ``constrained`` (always True for the other rules)."""
        if self.rule != "constrained" or not self.scores:
            return True
        return s.miou >= self.scores[0].miou - self.tolerance_points / POINTS - 1e-12

    def better(self, s: ValidationScore, than: ValidationScore) -> bool:
        if self.rule == "val_loss":
            return s.loss < than.loss - MIN_DELTA
        if self.rule == "val_miou":
            return s.miou > than.miou + MIN_DELTA
        return self.admissible(s) and s.mece < than.mece - MIN_DELTA

    def update(self, score: ValidationScore) -> bool:
        """Record a check; True if its checkpoint is the new best (keep its parameters)."""
        if self.stop:
            raise RuntimeError("update() after the selector stopped training")
        self.scores.append(score)
        if self.best_index < 0:
            self.best_index = 0
            return True
        if self.better(score, self.best):
            self.best_index, self.stale = len(self.scores) - 1, 0
            return True
        self.stale += 1
        self.stop = self.stale >= self.patience
        return False
