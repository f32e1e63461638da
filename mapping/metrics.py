"""Accuracy and calibration metrics of probabilistic classifications (paper Sec. III-C, which
defines ECE, TL-ECE and mECE): ``accuracy``, ``miou`` / ``per_class_iou``, ``ece``, ``tl_ece``,
``mece``, ``brier``; ``reliability`` returns a ``ReliabilityTable`` (per-bin data for
reliability diagrams, see ``eval/calibration/plots.py``).

Every function takes ``probs`` (N, K) float (rows are probability vectors) and ``labels`` (N,)
int class ids, plus ``n_bins`` (calibration bins; accepted and ignored by the non-binned
metrics so all share one call signature) and ``ignore_index`` (a label value whose samples are
left out, e.g. ``-1`` for void). They return a Python float (``per_class_iou``: a (K,) array).

Binning: ``n_bins`` equal-width bins on the top-label confidence h = max_k probs[k]. Bin b
covers [b / n_bins, (b + 1) / n_bins): the *left* edge is closed, so h = 0.1 falls in bin 1
(of 10); the last bin is closed on both sides, so h = 1.0 falls in bin n_bins - 1. The bin is
computed as floor(h * n_bins) in float64, clipped to n_bins - 1 (a float32 confidence is
binned by its exact value: float32(0.7) = 0.69999999 lies in bin 6).

Definitions (|B| = samples in a bin, acc = fraction of them whose argmax is the label,
conf = their mean top-label confidence, N = samples after ``ignore_index``):

- ECE    = sum_b |B_b| / N |acc(B_b) - conf(B_b)|
- TL-ECE = sum_{b,k} |B_bk| / N |acc(B_bk) - conf(B_bk)|, B_bk = samples of bin b
  *predicted* as k
- mECE   = mean over classes c present in ``labels`` of
  sum_b |B_bc| / N_c |acc(B_bc) - conf(B_bc)|, B_bc = samples of bin b whose *label* is c
  (N_c of them); classes absent from the labels are skipped
- Brier  = mean over samples of sum_k (probs[k] - onehot(label)[k])^2  (0 .. 2)
- IoU_c  = TP / (TP + FP + FN) on the argmax; mIoU = mean over classes present in the
  *labels* (calnav's convention, ``convention="calnav"``; ``present="either"`` also counts
  classes that are only predicted, each with IoU 0). Ties in the argmax go to the lowest class id.
- The authors' released mIoU (``convention="authors"``): void samples (``ignore_index``) that
  are predicted as class c count as false positives of c, IoU_c = TP / (TP + FP + FN + V_c);
  the classes in ``exclude`` (their class 0, ScanNet's "unannotated") are left out; the mean
  runs over the classes present in the labels OR the predictions (void samples' included).

Memory: the metrics accumulate a (n_bins, K, K) table of counts and confidence sums (and a
Brier sum) with ``np.bincount`` in chunks of ``CHUNK_ROWS`` rows, so 10^7 pixels need no
(N, K) temporaries beyond a chunk. ``CalibrationStats`` exposes the accumulator itself for
streaming evaluation (update frame by frame, read every metric at the end).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np

DEFAULT_BINS = 10          # the paper's bin count
CHUNK_ROWS = 1 << 16       # rows processed per pass (temporaries ~CHUNK_ROWS * K * 8 B = 9 MiB at K = 18)
SUM_TOLERANCE = 1e-2       # |row sum - 1| allowed (fp16 softmax outputs sum to 1 within ~1e-3)
PRESENT_CHOICES = ("labels", "either")
MIOU_CONVENTIONS = ("calnav", "authors")
AUTHORS_EXCLUDED_CLASSES = (0,)   # the authors' class 0 (ScanNet "unannotated") is left out of their mean


@dataclass(frozen=True, eq=False)
class ReliabilityTable:
    """Reliability-diagram data (``CalibrationStats.reliability``). B = n_bins, K = classes.

    edges (B + 1,) float64 bin edges on top-label confidence (0 .. 1, equal width).
    count (B,) int64 samples per bin. accuracy / confidence (B,) float64 fraction correct /
    mean top-label confidence per bin (NaN for empty bins).
    class_count (K, B) int64, class_accuracy / class_confidence (K, B) float64: the same,
    restricted to samples whose *ground-truth* label is the class (mECE's conditioning; NaN
    where empty). ece / mece: the scalar metrics (float, NaN without samples).
    """
    edges: np.ndarray
    count: np.ndarray
    accuracy: np.ndarray
    confidence: np.ndarray
    class_count: np.ndarray
    class_accuracy: np.ndarray
    class_confidence: np.ndarray
    ece: float
    mece: float

    @property
    def centers(self) -> np.ndarray:
        """(B,) bin centres."""
        return 0.5 * (self.edges[:-1] + self.edges[1:])

    def class_ece(self) -> np.ndarray:
        """(K,) within-class ECE (NaN for classes without samples)."""
        n_c = self.class_count.sum(axis=1).astype(np.float64)
        gap = np.nansum(self.class_count * np.abs(self.class_accuracy - self.class_confidence), axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(n_c > 0, gap / np.maximum(n_c, 1.0), np.nan)


def iou_of_confusion(confusion: np.ndarray, present: str = "labels") -> np.ndarray:
    """(K,) float64 IoU per class of a (K_pred, K_true) confusion count table; NaN for classes
    not present (``present``: in the labels, or ``either`` labels or predictions)."""
    if present not in PRESENT_CHOICES:
        raise ValueError(f"present must be one of {', '.join(PRESENT_CHOICES)}, got {present!r}")
    conf = np.asarray(confusion, dtype=np.float64)
    if conf.ndim != 2 or conf.shape[0] != conf.shape[1]:
        raise ValueError(f"confusion must be a (K, K) table, got shape {conf.shape}")
    tp = np.diag(conf)
    predicted, actual = conf.sum(axis=1), conf.sum(axis=0)
    union = predicted + actual - tp
    keep = actual > 0 if present == "labels" else union > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(keep, tp / np.maximum(union, 1.0), np.nan)


class CalibrationStats:
    """Streaming accumulator of everything the metrics need.

    num_classes: K. n_bins: confidence bins. ``update`` adds samples; the metric methods read
    the totals (NaN when no sample has been added). Tables: ``count`` (n_bins, K_pred, K_true)
    int64 and ``conf_sum`` (same shape) float64 sums of top-label confidence; ``brier_sum``;
    ``void_pred`` (K,) int64 argmax counts of the ignored (void) samples, filled only by
    ``update(..., count_ignored=True)`` (the authors' mIoU counts them as false positives).
    """

    def __init__(self, num_classes: int, n_bins: int = DEFAULT_BINS):
        if int(num_classes) < 1:
            raise ValueError(f"num_classes must be >= 1, got {num_classes}")
        if int(n_bins) < 1:
            raise ValueError(f"n_bins must be >= 1, got {n_bins}")
        self.num_classes, self.n_bins = int(num_classes), int(n_bins)
        shape = (self.n_bins, self.num_classes, self.num_classes)
        self.count = np.zeros(shape, dtype=np.int64)
        self.conf_sum = np.zeros(shape, dtype=np.float64)
        self.brier_sum = 0.0
        self.void_pred = np.zeros(self.num_classes, dtype=np.int64)

    @property
    def n(self) -> int:
        """Samples accumulated so far."""
        return int(self.count.sum())

    # ------------------------------------------------------------------ accumulate
    def update(self, probs: np.ndarray, labels: np.ndarray, ignore_index: int | None = None,
               count_ignored: bool = False) -> "CalibrationStats":
        """Add samples: probs (N, K) float, labels (N,) int; rows whose label equals
        ``ignore_index`` are skipped (with ``count_ignored``, their argmax is added to
        ``void_pred``; such rows must then be finite). Raises ValueError on bad shapes, NaN / out-of-range
        probabilities or labels outside [0, K). Returns self."""
        probs, labels = _check_inputs(probs, labels, self.num_classes)
        k, nb = self.num_classes, self.n_bins
        size = nb * k * k
        for start in range(0, len(labels), CHUNK_ROWS):
            p = probs[start:start + CHUNK_ROWS]
            y = labels[start:start + CHUNK_ROWS].astype(np.int64)
            if ignore_index is not None:
                keep = y != ignore_index
                if not keep.all():
                    if count_ignored:
                        void = p[~keep]
                        if not np.isfinite(void).all():
                            raise ValueError("probs of ignored (void) samples contain NaN or inf")
                        self.void_pred += np.bincount(void.argmax(axis=1), minlength=k)
                    p, y = p[keep], y[keep]
            if len(y) == 0:
                continue
            _check_chunk(p, y, k)
            p64 = p.astype(np.float64, copy=False)
            pred = p64.argmax(axis=1)
            conf = p64[np.arange(len(y)), pred]
            bins = np.minimum(np.floor(conf * nb).astype(np.int64), nb - 1)
            index = (bins * k + pred) * k + y
            self.count += np.bincount(index, minlength=size).reshape(nb, k, k)
            self.conf_sum += np.bincount(index, weights=conf, minlength=size).reshape(nb, k, k)
            # sum_k (p_k - onehot_k)^2 = sum_k p_k^2 - 2 p_y + 1, without a one-hot array
            p_true = p64[np.arange(len(y)), y]
            self.brier_sum += float(np.einsum("ij,ij->", p64, p64) - 2.0 * p_true.sum() + len(y))
        return self

    # ---------------------------------------------------------------------- read
    def confusion(self) -> np.ndarray:
        """(K_pred, K_true) int64 confusion counts."""
        return self.count.sum(axis=0)

    def _correct(self) -> np.ndarray:
        """(n_bins, K) correct predictions per bin and class (pred == label == k)."""
        k = np.arange(self.num_classes)
        return self.count[:, k, k]

    def error_bins(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per confidence bin: correct (n_bins,) int64 and wrong (n_bins,) int64 sample counts, and
        the wrong samples' confidence sums (n_bins,) float64 (error-vs-confidence plots)."""
        correct = self._correct().sum(axis=1)
        k = np.arange(self.num_classes)
        wrong_conf = self.conf_sum.sum(axis=(1, 2)) - self.conf_sum[:, k, k].sum(axis=1)
        return correct, self.count.sum(axis=(1, 2)) - correct, wrong_conf

    def accuracy(self) -> float:
        n = self.n
        return float(self._correct().sum() / n) if n else float("nan")

    def ece(self) -> float:
        n = self.n
        if not n:
            return float("nan")
        gap = self._correct().sum(axis=1) - self.conf_sum.sum(axis=(1, 2))  # (n_bins,) = |B| (acc - conf)
        return float(np.abs(gap).sum() / n)

    def tl_ece(self) -> float:
        n = self.n
        if not n:
            return float("nan")
        gap = self._correct() - self.conf_sum.sum(axis=2)                   # (n_bins, K_pred)
        return float(np.abs(gap).sum() / n)

    def per_class_ece(self) -> np.ndarray:
        """(K,) ECE within each ground-truth class (NaN for classes absent from the labels)."""
        n_c = self.count.sum(axis=(0, 1)).astype(np.float64)                 # (K_true,)
        gap = np.abs(self._correct() - self.conf_sum.sum(axis=1)).sum(axis=0)  # (K_true,)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(n_c > 0, gap / np.maximum(n_c, 1.0), np.nan)

    def mece(self) -> float:
        per = self.per_class_ece()
        return float(np.nanmean(per)) if np.isfinite(per).any() else float("nan")

    def brier(self) -> float:
        n = self.n
        return float(self.brier_sum / n) if n else float("nan")

    def per_class_iou(self, present: str = "labels") -> np.ndarray:
        """(K,) float64 IoU per class; NaN for classes not present (see the module docstring)."""
        return iou_of_confusion(self.confusion(), present)

    def per_class_iou_authors(self, exclude: Iterable[int] = AUTHORS_EXCLUDED_CLASSES) -> np.ndarray:
        """(K,) float64 IoU per class in the authors' convention (module docstring): void
        predictions are false positives; NaN for excluded classes and classes neither labelled
        nor predicted."""
        conf = self.confusion().astype(np.float64)
        tp = np.diag(conf)
        predicted = conf.sum(axis=1) + self.void_pred
        union = predicted + conf.sum(axis=0) - tp
        keep = union > 0
        ids = _class_ids(exclude, self.num_classes, "exclude")
        keep[ids] = False
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(keep, tp / np.maximum(union, 1.0), np.nan)

    def miou(self, classes: Iterable[int] | None = None, present: str = "labels", convention: str = "calnav",
             exclude: Iterable[int] = AUTHORS_EXCLUDED_CLASSES) -> float:
        """Mean IoU over present classes, optionally only those in ``classes`` (ids).
        ``convention``: ``calnav`` (``present`` applies) or ``authors`` (``exclude`` applies)."""
        if convention not in MIOU_CONVENTIONS:
            raise ValueError(f"convention must be one of {', '.join(MIOU_CONVENTIONS)}, got {convention!r}")
        iou = self.per_class_iou(present) if convention == "calnav" else self.per_class_iou_authors(exclude)
        if classes is not None:
            iou = iou[_class_ids(classes, self.num_classes, "classes")]
        return float(np.nanmean(iou)) if np.isfinite(iou).any() else float("nan")

    def reliability(self) -> ReliabilityTable:
        """Per-bin count / accuracy / mean confidence, overall and per ground-truth class
        (see ``ReliabilityTable`` for shapes; empty bins are NaN)."""
        correct = self._correct()                                            # (n_bins, K)
        count = self.count.sum(axis=(1, 2))                                  # (n_bins,)
        class_count = self.count.sum(axis=1).T.copy()                        # (K_true, n_bins)
        class_conf = self.conf_sum.sum(axis=1).T                             # (K_true, n_bins)
        return ReliabilityTable(
            edges=np.linspace(0.0, 1.0, self.n_bins + 1),
            count=count, accuracy=_ratio(correct.sum(axis=1), count),
            confidence=_ratio(self.conf_sum.sum(axis=(1, 2)), count),
            class_count=class_count, class_accuracy=_ratio(correct.T, class_count),
            class_confidence=_ratio(class_conf, class_count), ece=self.ece(), mece=self.mece())

    def summary(self) -> dict[str, float]:
        """All scalar metrics in one dict."""
        return {"accuracy": self.accuracy(), "miou": self.miou(), "ece": self.ece(), "tl_ece": self.tl_ece(),
                "mece": self.mece(), "brier": self.brier(), "n": float(self.n)}


def _class_ids(ids: Iterable[int], num_classes: int, what: str) -> np.ndarray:
    """Class ids as an int64 array, checked to lie in [0, K)."""
    out = np.asarray(list(ids), dtype=np.int64)
    if out.size and (out.min() < 0 or out.max() >= num_classes):
        raise ValueError(f"{what} must be class ids in [0, {num_classes}), got {out.tolist()}")
    return out


def _ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """num / den as float64, NaN where den == 0 (no warnings)."""
    return np.where(den > 0, num / np.maximum(den, 1), np.nan).astype(np.float64)


# ------------------------------------------------------------------------- validation
def _check_inputs(probs: np.ndarray, labels: np.ndarray, num_classes: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    probs, labels = np.asarray(probs), np.asarray(labels)
    if probs.ndim != 2:
        raise ValueError(f"probs must be (N, K), got shape {probs.shape}")
    if labels.ndim != 1:
        raise ValueError(f"labels must be (N,), got shape {labels.shape}")
    if len(probs) != len(labels):
        raise ValueError(f"probs and labels disagree on N: probs {probs.shape}, labels {labels.shape}")
    if num_classes is not None and probs.shape[1] != num_classes:
        raise ValueError(f"probs has K = {probs.shape[1]} columns, expected {num_classes}")
    if not np.issubdtype(probs.dtype, np.floating):
        raise ValueError(f"probs must be floating point, got {probs.dtype}")
    if not (np.issubdtype(labels.dtype, np.integer) or labels.dtype == bool):
        raise ValueError(f"labels must be integer class ids, got {labels.dtype}")
    return probs, labels


def _check_chunk(p: np.ndarray, y: np.ndarray, k: int) -> None:
    """Value checks on one chunk (after ignore_index): finite probabilities in [0, 1] whose rows
    sum to 1, labels in [0, K)."""
    if not np.isfinite(p).all():
        raise ValueError("probs contain NaN or inf")
    if p.min() < -SUM_TOLERANCE or p.max() > 1 + SUM_TOLERANCE:
        raise ValueError(f"probs must lie in [0, 1], got values in [{p.min():.4g}, {p.max():.4g}]")
    sums = p.sum(axis=1, dtype=np.float64)
    worst = float(np.abs(sums - 1.0).max())
    if worst > SUM_TOLERANCE:
        raise ValueError(f"probs rows must sum to 1 (within {SUM_TOLERANCE}); worst row sums to "
                         f"{sums[np.argmax(np.abs(sums - 1.0))]:.4g} -- pass softmax(logits), not logits")
    if y.min() < 0 or y.max() >= k:
        bad = np.unique(y[(y < 0) | (y >= k)])[:10]
        raise ValueError(f"labels must be class ids in [0, {k}) (or ignore_index), found {bad.tolist()}")


def _stats(probs, labels, n_bins: int, ignore_index: int | None, count_ignored: bool = False) -> CalibrationStats:
    probs, labels = _check_inputs(probs, labels)
    stats = CalibrationStats(probs.shape[1], n_bins).update(probs, labels, ignore_index, count_ignored)
    if stats.n == 0:
        raise ValueError("no samples left to score (empty input, or every label is ignore_index)")
    return stats


# ---------------------------------------------------------------------- functional api
def accuracy(probs, labels, n_bins: int = DEFAULT_BINS, ignore_index: int | None = None) -> float:
    """Fraction of samples whose argmax equals the label (n_bins unused)."""
    return _stats(probs, labels, n_bins, ignore_index).accuracy()


def ece(probs, labels, n_bins: int = DEFAULT_BINS, ignore_index: int | None = None) -> float:
    """Expected calibration error over top-label confidence bins."""
    return _stats(probs, labels, n_bins, ignore_index).ece()


def tl_ece(probs, labels, n_bins: int = DEFAULT_BINS, ignore_index: int | None = None) -> float:
    """Top-label ECE: bins conditioned on the predicted class."""
    return _stats(probs, labels, n_bins, ignore_index).tl_ece()


def mece(probs, labels, n_bins: int = DEFAULT_BINS, ignore_index: int | None = None) -> float:
    """Mean over ground-truth classes of the within-class ECE."""
    return _stats(probs, labels, n_bins, ignore_index).mece()


def brier(probs, labels, n_bins: int = DEFAULT_BINS, ignore_index: int | None = None) -> float:
    """Mean over samples of the squared distance to the one-hot label (n_bins unused)."""
    return _stats(probs, labels, n_bins, ignore_index).brier()


def per_class_iou(probs, labels, n_bins: int = DEFAULT_BINS, ignore_index: int | None = None,
                  present: str = "labels") -> np.ndarray:
    """(K,) IoU per class, NaN where the class is not present (n_bins unused)."""
    return _stats(probs, labels, n_bins, ignore_index).per_class_iou(present)


def miou(probs, labels, n_bins: int = DEFAULT_BINS, ignore_index: int | None = None,
         classes: Iterable[int] | None = None, present: str = "labels", convention: str = "calnav",
         exclude: Iterable[int] = AUTHORS_EXCLUDED_CLASSES) -> float:
    """Mean IoU over present classes (optionally restricted to ``classes``; n_bins unused).
    ``convention="authors"``: the authors' release (module docstring); samples labelled
    ``ignore_index`` are then void false positives of their predicted class."""
    if convention not in MIOU_CONVENTIONS:
        raise ValueError(f"convention must be one of {', '.join(MIOU_CONVENTIONS)}, got {convention!r}")
    return _stats(probs, labels, n_bins, ignore_index, count_ignored=convention == "authors").miou(
        classes, present, convention, exclude)


def reliability(probs, labels, n_bins: int = DEFAULT_BINS, ignore_index: int | None = None) -> ReliabilityTable:
    """Reliability-diagram data: per-bin counts, accuracy and confidence (overall and per class)."""
    return _stats(probs, labels, n_bins, ignore_index).reliability()
