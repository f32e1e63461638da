"""``noisy``: ground truth corrupted by a controllable, documented error model.

Real segmentation networks make errors that are *correlated across views* (the same object is
mistaken again from the next frame), grow with distance and grazing angle, and come with
overconfident scores. This segmenter reproduces those three properties on top of the
ground-truth ``semantic`` image, deterministically: every random choice is a hash of
(``seed``, a stable key), never a draw from a generator, so the same inputs and seed give the
same logits, and the same object / place gets the same fate in every frame.

Error model (all parameters in ``SegmenterConfig``):

1. Instance confusions. Each object instance (key: its id in the ``instance`` image; without
   that image, its class id, so all instances of a class share one fate) whose class has
   entries in ``confusions`` is "confusable" with probability ``instance_confusion_prob``; it
   then has one wrong class (a hashed pick from its confusion list) and a hashed arc of
   ``confusion_arc_deg`` viewing azimuths. In a frame, the instance's whole visible region is
   labelled with the wrong class when the world azimuth of the mean viewing ray onto its pixels
   lies inside the arc (needs ``pose``; without a pose the confusion holds from every
   viewpoint). Nearby viewpoints see the instance from nearly the same azimuth, so they agree.
2. Distance / grazing errors, world-anchored. Every visible surface point falls in a world
   cell of ``error_cell_m`` (camera-frame cells without ``pose``), which draws a fixed
   uniform u. A pixel is wrong when u < p_err, with
       p_err = min(max_error, base_error + error_per_m * max(0, r - near_m)
                              + grazing_error * (1 - cos(incidence)))
   r = the pixel's range in metres (``invalid_depth_m`` where depth is 0) and incidence the
   angle between the viewing ray and the surface normal estimated from the depth image. Its
   wrong class is a hashed pick from the true class's entries in ``confusions`` plus
   ``cell_confusions`` (surfaces like walls and floors, too big to be confused as a whole), or
   from all other classes when it has none. A cell is thus wrong from far / oblique views and right
   from near, frontal ones, consistently across frames.
3. Overconfident logits. The "calibrated" probability of the predicted class is 1 - e, with
   e = q + (1 - q) p_err the expected error rate at the pixel (q = instance_confusion_prob *
   arc / 360 for a confusable predicted class, else 0); ``runner_up_share`` of e goes to the
   runner-up (the true class when the pixel is wrong, otherwise a confusion partner), the rest
   spreads evenly (e is capped at MAX_EXPECTED_ERROR so the predicted class stays on top).
   Logits are log(probabilities) / ``temperature``; temperature < 1 sharpens
   them, so confidence exceeds accuracy. Void pixels (semantic < 0) get uniform (zero) logits.
"""
from __future__ import annotations

import numpy as np

from calnav.agent.segmenters.base import Segmenter, SegmenterConfig, check_frame, check_label_image

# Salts keep the hashed choices of different error types independent.
SALT_CELL, SALT_ALT, SALT_INST, SALT_PARTNER, SALT_ARC, SALT_CLASS_KEY = range(1, 7)
_M1, _M2 = np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB)  # splitmix64 constants
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
MIN_PROB = 1e-6                 # floor of any class probability before the log (finite logits)
NORMAL_EPS = 1e-9               # guards the normal / ray normalisations
MAX_EXPECTED_ERROR = 0.45       # cap on e, so the predicted class keeps the top score (1 - e > e)


def _mix(x: np.ndarray) -> np.ndarray:
    """splitmix64 finaliser on uint64 (wrapping arithmetic)."""
    x = x ^ (x >> np.uint64(30))
    x = x * _M1
    x = x ^ (x >> np.uint64(27))
    x = x * _M2
    return x ^ (x >> np.uint64(31))


def hash_keys(*keys) -> np.ndarray:
    """Hash integer arrays / scalars (broadcast together) into one uint64 array."""
    with np.errstate(over="ignore"):
        h = np.uint64(0)
        for k in keys:
            k = np.asarray(k).astype(np.int64).view(np.uint64)
            h = _mix((h ^ k) + _GOLDEN)
    return np.asarray(h)


def to_uniform(h: np.ndarray) -> np.ndarray:
    """uint64 hashes -> float64 in [0, 1) (top 53 bits)."""
    return (h >> np.uint64(11)).astype(np.float64) * (1.0 / (1 << 53))


class NoisySegmenter(Segmenter):
    """segment(rgb, depth, semantic=..., instance=None, pose=None) -> (H, W, K) float32 logits.
    Privileged by declaration (``agent.contract``): the agent hands it the simulator's camera
    pose and the instance image when the observation has them."""

    name = "noisy"
    needs_semantic = True
    needs_depth = True
    # agent.contract's CAMERA_POSE and INSTANCE, spelt out: a segmenter loads without the simulator's
    # package (envs), which agent.contract imports; a misspelt name fails when the agent hands them
    privileged = ("camera_pose", "instance")

    def __init__(self, cfg: SegmenterConfig, class_names: tuple[str, ...]):
        self.cfg = cfg
        self.class_names = tuple(class_names)
        k = len(self.class_names)
        if k < 3:
            raise ValueError(f"noisy segmenter needs at least 3 classes, got {k}")
        self.partners, self.n_partners = self._table(cfg.confusions)          # instances and cells
        merged = {n: list(v) for n, v in cfg.confusions.items()}
        for n, extra in cfg.cell_confusions.items():
            merged[n] = merged.get(n, []) + [e for e in extra if e not in merged.get(n, [])]
        self.cell_partners, self.n_cell_partners = self._table(merged)           # cells only
        self.arc_rad = np.deg2rad(cfg.confusion_arc_deg)
        # expected instance-confusion rate of a confusable class (used for the "calibrated" score)
        self.q_instance = np.where(self.n_partners > 0, cfg.instance_confusion_prob * cfg.confusion_arc_deg / 360.0, 0.0)

    def _table(self, confusions: dict[str, list[str]]) -> tuple[np.ndarray, np.ndarray]:
        """(K, P) int64 confusable class ids per class (-1 padded) and (K,) their counts."""
        k = self.num_classes
        index = {n: i for i, n in enumerate(self.class_names)}
        width = max([len(v) for v in confusions.values()] + [1])
        partners = np.full((k, width), -1, dtype=np.int64)
        count = np.zeros(k, dtype=np.int64)
        for name, others in confusions.items():
            for n in [name, *others]:
                if n not in index:
                    raise ValueError(f"segmenter confusion table: unknown class {n!r}; valid classes: "
                                     f"{', '.join(self.class_names)}")
            ids = [index[o] for o in others if o != name]
            partners[index[name], :len(ids)] = ids
            count[index[name]] = len(ids)
        return partners, count

    # ------------------------------------------------------------------ geometry
    def _geometry(self, depth: np.ndarray, pose: np.ndarray | None):
        """Per-pixel range (H, W) m, cos(incidence) (H, W), surface points (H, W, 3) m and unit
        viewing rays (H, W, 3), both in the world frame (camera frame without a pose)."""
        h, w = depth.shape
        f = (w / 2.0) / np.tan(np.deg2rad(self.cfg.hfov_deg) / 2.0)
        x = (np.arange(w) - (w - 1) / 2.0) / f
        y = (np.arange(h) - (h - 1) / 2.0) / f
        ray = np.empty((h, w, 3))
        ray[..., 0], ray[..., 1], ray[..., 2] = x[None, :], y[:, None], 1.0  # z = 1: depth is z-depth
        valid = depth > 0
        z = np.where(valid, depth, 0.0).astype(np.float64)
        norm = np.linalg.norm(ray, axis=-1)
        # invalid depth: put the point at invalid_depth_m along the ray (range known only as "far")
        z = np.where(valid, z, self.cfg.invalid_depth_m / norm)
        pts = ray * z[..., None]
        rng_m = z * norm
        du, dv = np.gradient(pts, axis=1), np.gradient(pts, axis=0)
        n = np.cross(du, dv)
        cos_inc = np.abs((n * ray).sum(-1)) / (np.linalg.norm(n, axis=-1) * norm + NORMAL_EPS)
        cos_inc = np.where(valid, np.clip(cos_inc, 0.0, 1.0), 1.0)
        unit = ray / norm[..., None]
        if pose is not None:
            rot, t = pose[:3, :3], pose[:3, 3]
            pts = pts @ rot.T + t
            unit = unit @ rot.T
        return rng_m, cos_inc, pts, unit

    def error_probability(self, range_m: np.ndarray, cos_inc: np.ndarray) -> np.ndarray:
        """p_err (see the module docstring) for ranges (metres) and cos(incidence)."""
        c = self.cfg
        p = c.base_error + c.error_per_m * np.maximum(0.0, range_m - c.near_m) + c.grazing_error * (1.0 - cos_inc)
        return np.minimum(p, c.max_error)

    def _pick_other(self, cls: np.ndarray, h: np.ndarray, cells: bool = False) -> np.ndarray:
        """A hashed wrong class for each true class ``cls``: a confusion partner if it has any
        (``cells``: from the merged instance + cell table), else any other class."""
        k = self.num_classes
        table, counts = (self.cell_partners, self.n_cell_partners) if cells else (self.partners, self.n_partners)
        n_p = counts[cls]
        partner = table[cls, (h % np.maximum(n_p, 1).astype(np.uint64)).astype(np.int64)]
        other = (cls + 1 + (h % np.uint64(k - 1)).astype(np.int64)) % k
        return np.where(n_p > 0, partner, other)

    def _instance_confusions(self, sem, inst, unit, valid, posed: bool) -> tuple[np.ndarray, np.ndarray]:
        """(mask (H, W) bool of pixels whose instance is currently confused, wrong class (H, W))."""
        c = self.cfg
        keys = np.where(valid, inst, -1) if inst is not None else np.where(valid, sem, -1)
        salt = SALT_INST if inst is not None else SALT_CLASS_KEY
        flat = keys.ravel()
        sel = np.flatnonzero(valid.ravel() & (flat >= 0))
        mask = np.zeros(sem.shape, dtype=bool)
        wrong = np.zeros(sem.shape, dtype=np.int64)
        if sel.size == 0:
            return mask, wrong
        uniq, first, inverse = np.unique(flat[sel], return_index=True, return_inverse=True)
        cls = sem.ravel()[sel[first]].astype(np.int64)        # an instance has one class
        h = hash_keys(c.seed, salt, uniq)
        confusable = (to_uniform(h) < c.instance_confusion_prob) & (self.n_partners[cls] > 0)
        partner = self._pick_other(cls, hash_keys(h, SALT_PARTNER))
        if posed and self.arc_rad < 2 * np.pi:
            # world azimuth of the mean viewing ray onto each instance's visible pixels
            rays = unit.reshape(-1, 3)[sel]
            sx = np.bincount(inverse, weights=rays[:, 0], minlength=len(uniq))
            sy = np.bincount(inverse, weights=rays[:, 1], minlength=len(uniq))
            azimuth = np.arctan2(sy, sx)
            start = to_uniform(hash_keys(h, SALT_ARC)) * 2 * np.pi
            in_arc = np.mod(azimuth - start, 2 * np.pi) < self.arc_rad
            confusable &= in_arc
        mask.ravel()[sel] = confusable[inverse]
        wrong.ravel()[sel] = partner[inverse]
        return mask, wrong

    # -------------------------------------------------------------------- segment
    def segment(self, rgb: np.ndarray, depth: np.ndarray | None = None, semantic: np.ndarray | None = None,
                instance: np.ndarray | None = None, pose: np.ndarray | None = None, **_unused) -> np.ndarray:
        """rgb (H, W, 3) uint8 (shape check only), depth (H, W) float32 metres (0 = invalid),
        semantic (H, W) int class ids (-1 void), instance (H, W) int ids (-1 none) or None,
        pose (4, 4) world-from-camera (OpenCV axes) or None -> logits (H, W, K) float32."""
        c, k = self.cfg, self.num_classes
        rgb, depth = check_frame(rgb, depth, need_depth=True)
        shape = rgb.shape[:2]
        sem = check_label_image("semantic", semantic, shape).astype(np.int64)
        inst = None if instance is None else check_label_image("instance", instance, shape).astype(np.int64)
        if pose is not None:
            pose = np.asarray(pose, dtype=np.float64)
            if pose.shape != (4, 4) or not np.isfinite(pose).all():
                raise ValueError(f"pose must be a finite (4, 4) world-from-camera matrix, got shape {pose.shape}")
        valid = (sem >= 0) & (sem < k)
        safe = np.where(valid, sem, 0)
        range_m, cos_inc, pts, unit = self._geometry(depth, pose)
        p_err = self.error_probability(range_m, cos_inc)

        # 2. world-anchored distance / grazing errors
        cells = np.floor(pts / c.error_cell_m).astype(np.int64)
        h_cell = hash_keys(c.seed, SALT_CELL, cells[..., 0], cells[..., 1], cells[..., 2])
        cell_wrong = valid & (to_uniform(h_cell) < p_err)
        pred = np.where(cell_wrong, self._pick_other(safe, hash_keys(h_cell, SALT_ALT), cells=True), safe)
        # 1. instance confusions (override: the whole visible instance is mistaken)
        inst_mask, inst_class = self._instance_confusions(sem, inst, unit, valid, pose is not None)
        pred = np.where(inst_mask, inst_class, pred)

        # 3. overconfident scores around the (possibly wrong) prediction
        q = self.q_instance[pred]
        e = np.clip(q + (1.0 - q) * p_err, MIN_PROB, MAX_EXPECTED_ERROR)
        alt = self._pick_other(pred, hash_keys(c.seed, SALT_ALT, pred), cells=True)
        runner = np.where(pred != safe, safe, alt)
        # three distinct probabilities per pixel: rest (spread evenly), runner-up and top
        rest = np.log(np.maximum(e * (1.0 - c.runner_up_share) / (k - 2), MIN_PROB)) / c.temperature
        logits = np.empty((*shape, k), dtype=np.float32)
        logits[...] = rest[..., None]
        np.put_along_axis(logits, runner[..., None],
                          (np.log(np.maximum(e * c.runner_up_share, MIN_PROB)) / c.temperature)[..., None], axis=-1)
        np.put_along_axis(logits, pred[..., None], (np.log(1.0 - e) / c.temperature)[..., None], axis=-1)
        logits[~valid] = 0.0
        return logits
