"""The segmenter interface and its configuration.

A segmenter turns one RGB-D frame into per-pixel class scores:

    logits = segmenter(rgb, depth)                 # (H, W, 3) uint8, (H, W) float32 m -> (H, W, K) float32
    batch = segmenter.segment_batch(rgbs, depths)  # (B, H, W, 3), (B, H, W) -> (B, H, W, K)

``softmax(logits)`` (below) are the class probabilities. K and the class names
(``segmenter.class_names``) are data: the learned networks carry them in their weights file,
the ground-truth based segmenters take them from ``agent/weights/classes.json`` (a copy of the
simulator's ``envs.semantics.CLASS_NAMES``, checked by a test). Every segmenter's channels are
matched to these classes by name (``calnav_class_order``: a plugged-in model or weight file
listing them in another order gives its logits in calnav's order; duplicates and other names
are refused), and the agent finds its goal's channel by name: the task's ``objectgoal`` id
names a goal category (``goal_categories``), never a channel. Nothing here reads the simulator
(the agent does import ``envs.task`` for the action ids, the task's contract).

Segmenters built from ground truth (``gt``, ``noisy``) additionally need the environment's
``semantic`` observation ((H, W) int class ids, -1 = void); ``noisy`` also uses the
``instance`` observation ((H, W) int instance ids, -1 = none) and the camera ``pose``
((4, 4) world-from-camera, OpenCV axes) when given. They are passed as keywords:
``segmenter(rgb, depth, semantic=obs["semantic"], instance=..., pose=...)``.
"""
from __future__ import annotations

import json
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calnav.common.ranges import Range

WEIGHTS_DIR = Path(__file__).resolve().parents[1] / "weights"
CLASSES_FILE = WEIGHTS_DIR / "classes.json"


def default_confusions() -> dict[str, list[str]]:
    """The noisy segmenter's confusion table: class -> classes it can be mistaken for."""
    return {
        "chair": ["stool"], "stool": ["chair"],
        "sofa": ["bed"], "bed": ["sofa"],
        "table": ["desk", "counter"], "desk": ["table", "counter"], "counter": ["table", "desk"],
        "cabinet": ["shelf", "tv_monitor"], "shelf": ["cabinet"], "tv_monitor": ["cabinet"],
        "toilet": ["sink", "bathtub"], "sink": ["toilet", "bathtub"], "bathtub": ["toilet", "sink"],
        "plant": ["shelf"],
        "door": ["wall"],
    }


def default_cell_confusions() -> dict[str, list[str]]:
    """Extra wrong classes for the noisy segmenter's world-cell errors only (surfaces too big
    to be mistaken as a whole instance): class -> classes a patch of it can be mistaken for."""
    return {"wall": ["door", "cabinet"], "floor": ["wall"], "ceiling": ["wall"]}


MIN_INPUT_SIDE_PX, MAX_INPUT_SIDE_PX = 16, 4096   # a network input below 16 px has no features left after
                                                # the encoder's downsampling; above 4096 px is no camera's
SEGMENTER_RANGES: dict[str, Range] = {
    "gt_confidence": Range(0, 1, lo_open=True),
    "instance_confusion_prob": Range(0, 1), "base_error": Range(0, 1), "max_error": Range(0, 1),
    "runner_up_share": Range(0, 1), "grazing_error": Range(0, 1),
    "error_per_m": Range(0, 1, "per metre"),             # a probability added per metre
    "temperature": Range(0.01, 100),                     # logits / T: beyond these, one-hot or uniform
    "error_cell_m": Range(0.01, 10, "metres"),           # cells right or wrong together: a cm to a room
    "near_m": Range(0, 100, "metres"), "invalid_depth_m": Range(0, 100, "metres"),   # indoor distances
    "hfov_deg": Range(0, 180, "degrees", lo_open=True, hi_open=True),
    "confusion_arc_deg": Range(0, 360, "degrees"),
    "threads": Range(0, 1024, "threads"),                # 0 = leave torch's setting
}


@dataclass
class SegmenterConfig:
    """Settings of every segmenter (YAML section ``segmenter``, for every command; unused keys
    are ignored by the segmenters that do not need them)."""

    # --- all -------------------------------------------------------------------------------
    device: str = ""                 # torch device ("cpu", "cuda", "cuda:1"); "" = run.device (else cpu); set, it wins
    tf32: bool = False               # CUDA: allow TensorFloat-32 convolutions / matmuls (Ampere and later). Off, the
                                     # logits match the CPU's float32 (measured on an H200: max |diff| 9e-6); on,
                                     # they differ by up to 1.4e-2 and 0.03 % of pixels change class, for no speed-up
                                     # on calnav's small networks (process-wide torch.backends settings)
    # --- gt ----------------------------------------------------------------------------------
    gt_confidence: float = 0.9       # probability given to the true class (rest spread evenly); (0, 1]
    # --- learned_rgb / learned_rgbd --------------------------------------------------------
    weights: str = ""                # weight file; "" = agent/weights/<name>.pt (learned_*)
    resolution: tuple[int, int] = (0, 0)  # network input WxH, pixels; (0, 0) = the training resolution in the weights file
    threads: int = 1                 # torch CPU threads (torch.set_num_threads, process-wide); 0 = leave as is.
                                     # 1: episodes run one worker per core, and on a busy 2-core machine two
                                     # OpenMP threads stall at barriers (measured 2-10 ms -> 400-900 ms per
                                     # frame) unless OMP_WAIT_POLICY=PASSIVE is set before torch loads
    trace: bool = True               # learned_*, CPU: run the network as a TorchScript trace, one per input shape (built
                                     # on first use, ~0.1 s): the same kernels without eager mode's per-module Python
                                     # work, so the logits are bit-identical; measured 1.77 -> 1.47 ms (rgb) and 2.87 ->
                                     # 2.32 ms (rgbd) per 160x120 frame, 1 thread (calnav bench). CUDA runs eager
    # --- plugged-in models: hf | onnx | a plugin (see agent.segmenters.adapter) -----------
    model: str = ""                  # hf: save_pretrained directory or hub id; onnx: .onnx file
    label_map: str = ""              # model classes -> calnav classes: "" = the model's own classes | ade20k | nyu40 |
                                     # scannet20 | coco_panoptic | a .tsv / .yaml / .json file (agent.segmenters.label_map)
    input_mean: list[float] = field(default_factory=list)  # onnx: per-channel mean of rgb / 255; [] = the model file's, else ImageNet's
    input_std: list[float] = field(default_factory=list)   # onnx: ... and standard deviation (> 0); [] = the model file's, else ImageNet's
    # --- noisy (ground truth + a controlled error model, see agent.segmenters.noisy) --------
    seed: int = 0                    # seeds every per-instance / per-cell random choice
    confusions: dict[str, list[str]] = field(default_factory=default_confusions)  # class -> confusable classes (instances and cells)
    cell_confusions: dict[str, list[str]] = field(default_factory=default_cell_confusions)  # class -> wrong classes of cell errors only
    instance_confusion_prob: float = 0.3  # fraction of instances (of confusable classes) that get mistaken
    confusion_arc_deg: float = 120.0  # viewing-azimuth arc (degrees) over which a mistaken instance is mistaken
    base_error: float = 0.02         # per-cell error probability up close and head-on
    near_m: float = 1.0              # errors grow beyond this distance, metres
    error_per_m: float = 0.04        # added error probability per metre beyond near_m
    grazing_error: float = 0.15      # added error probability at 90 deg incidence (scaled by 1 - cos(angle))
    max_error: float = 0.6           # cap on the per-cell error probability
    error_cell_m: float = 0.25       # size of the world-anchored cells that are right or wrong together, metres
    invalid_depth_m: float = 3.0     # distance assumed where depth is invalid (0: nearer than min or beyond max range), metres
    runner_up_share: float = 0.7     # share of the non-top probability given to the runner-up class
    temperature: float = 0.5         # logits = log(calibrated probs) / temperature; < 1 = overconfident
    hfov_deg: float = 79.0           # camera horizontal field of view (back-projection), degrees

    def __post_init__(self) -> None:
        # errors name the key without its section: the config loader prefixes it (``segmenter: ...``)
        for key, rng in SEGMENTER_RANGES.items():
            rng.check(key, getattr(self, key))   # NaN and inf fail every range
        for key in ("input_mean", "input_std"):
            values = getattr(self, key)
            if values and (len(values) != 3 or not all(math.isfinite(v) for v in values)):
                raise ValueError(f"{key} must be [] or 3 finite numbers (r, g, b), got {values}")
        if any(v <= 0 for v in self.input_std):
            raise ValueError(f"input_std must be > 0, got {self.input_std}")
        w, h = self.resolution
        if (w, h) != (0, 0) and not (MIN_INPUT_SIDE_PX <= min(w, h) and max(w, h) <= MAX_INPUT_SIDE_PX):
            raise ValueError(f"resolution must be (0, 0) or between {MIN_INPUT_SIDE_PX}x{MIN_INPUT_SIDE_PX} and "
                             f"{MAX_INPUT_SIDE_PX}x{MAX_INPUT_SIDE_PX} pixels, got {w}x{h}")


def softmax(logits: np.ndarray, temperature: float = 1.0) -> np.ndarray:
    """softmax(logits / temperature) over the last axis: (..., K) -> (..., K) float32."""
    z = logits / temperature
    z = z - z.max(axis=-1, keepdims=True)
    e = np.exp(z)
    return (e / e.sum(axis=-1, keepdims=True)).astype(np.float32)


def default_class_names() -> tuple[str, ...]:
    """The class list shipped with the weights (``agent/weights/classes.json``)."""
    try:
        return tuple(json.loads(CLASSES_FILE.read_text())["class_names"])
    except FileNotFoundError:
        raise FileNotFoundError(f"class list {CLASSES_FILE} is missing; pass class_names explicitly") from None


def task_goal_categories(agent_cfg) -> tuple[str, ...]:
    """What the task's objectgoal ids name, by id: ``agent.goal_categories`` when set (an episode
    file's categories), else calnav's (``goal_categories``)."""
    names = tuple(getattr(agent_cfg, "goal_categories", ()) or ())
    return names or goal_categories()


def goal_categories() -> tuple[str, ...]:
    """calnav's ObjectNav goal categories, shipped beside the class list (``classes.json``)."""
    try:
        return tuple(json.loads(CLASSES_FILE.read_text())["goal_categories"])
    except FileNotFoundError:
        raise FileNotFoundError(f"class list {CLASSES_FILE} is missing") from None


def class_list(names, source: str, valid: tuple[str, ...] = ()) -> tuple[str, ...]:
    """``names`` as a tuple of class names, or a one-line ValueError naming ``source`` (and the
    ``valid`` names, when given): a string (``class_names="wall"`` would read as the classes w,
    a, l, l), a non-list, a name that is not a string, an empty list, or a name listed twice
    (two channels of one class: every lookup by name would find only the first)."""
    if isinstance(names, (str, bytes)):
        raise ValueError(f"{source}: class_names must be a list of class names, got the string {names!r}")
    try:
        names = tuple(names)
    except TypeError:
        raise ValueError(f"{source}: class_names must be a list of class names, got {type(names).__name__}") from None
    bad = [n for n in names if not isinstance(n, str)]
    if bad:
        raise ValueError(f"{source}: class_names must be strings, got {bad[0]!r} ({type(bad[0]).__name__})")
    if not names:
        raise ValueError(f"{source}: class_names is empty")
    seen: set[str] = set()
    twice = list(dict.fromkeys(n for n in names if n in seen or seen.add(n)))
    if twice:
        raise ValueError(f"{source}: class_names lists {', '.join(map(repr, twice))} more than once; "
                         "every output channel needs its own class" + (f"; valid: {', '.join(valid)}" if valid else ""))
    return names


def calnav_class_order(names, source: str, hint: str = "") -> tuple[tuple[str, ...], tuple[int, ...] | None]:
    """Match a model's output channels to calnav's classes by name: ``names`` (the model's
    class list in channel order) must be distinct calnav classes (``default_class_names``).
    Returns (the classes in calnav's order, the channel of each) -- the channel order is None
    when the model's order is calnav's already. A model that predicts only some of calnav's
    classes keeps just those. ValueError (one line, ``source`` and ``hint`` in it) names the
    names that are not calnav classes and the valid ones."""
    calnav = default_class_names()
    names = class_list(names, source, calnav)
    unknown = [n for n in names if n not in calnav]
    if unknown:
        shown = ", ".join(map(repr, unknown[:8])) + (f", ... ({len(unknown)} of {len(names)})"
                                                     if len(unknown) > 8 else "")
        what = "is not a calnav class" if len(unknown) == 1 else "are not calnav classes"
        raise ValueError(f"{source}: {shown} {what}; valid: {', '.join(calnav)}{hint}")
    ordered = tuple(n for n in calnav if n in names)
    channels = tuple(names.index(n) for n in ordered)
    return ordered, (None if channels == tuple(range(len(names))) else channels)


def resolve_device(device: str | None, key: str = "device"):
    """torch.device for ``device`` ("" / None = cpu); a one-line error naming ``key`` (the
    config key that set it: ``run.device``, ``segmenter.device``) when it is no torch device,
    not cpu / cuda, or a CUDA device this machine does not have."""
    import torch

    name = (device or "cpu").strip()
    try:
        dev = torch.device(name)
    except RuntimeError:
        raise ValueError(f"{key}={name!r} is not a torch device; use 'cpu', 'cuda' or 'cuda:N'") from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"{key}={name!r} requested but CUDA is not available in this torch build / "
                             f"machine (torch {torch.__version__}); use {key}=cpu")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ValueError(f"{key}={name!r} requested but only {torch.cuda.device_count()} CUDA device(s) exist "
                             f"(cuda:0 to cuda:{torch.cuda.device_count() - 1})")
    elif dev.type != "cpu":
        raise ValueError(f"{key}={name!r} is not supported; use 'cpu', 'cuda' or 'cuda:N'")
    return dev


def segmenter_device(cfg: "SegmenterConfig", device: str | None, key: str = "segmenter") -> str:
    """The device a segmenter runs on, validated: its own ``<key>.device`` when set (it wins),
    else ``device`` (the caller's: ``run.device``), else cpu. ``key``: the segmenter section
    (``segmenter``), named in the error. Only a device other than cpu imports torch
    (the ground-truth segmenters run without it)."""
    name = (cfg.device or device or "cpu").strip()
    if name != "cpu":
        resolve_device(name, f"{key}.device" if cfg.device else "run.device")
    return name


def set_cuda_precision(device, tf32: bool) -> None:
    """On a CUDA ``device``, allow or forbid TensorFloat-32 (``SegmenterConfig.tf32``; torch
    allows it for cuDNN convolutions by default, so GPU logits would not be the CPU's)."""
    import torch

    if getattr(device, "type", str(device)) == "cuda":
        torch.backends.cudnn.allow_tf32 = bool(tf32)
        torch.backends.cuda.matmul.allow_tf32 = bool(tf32)


def check_frame(rgb: np.ndarray, depth: np.ndarray | None, need_depth: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """Validate one frame: rgb (H, W, 3) uint8, depth (H, W) float metres (None allowed unless
    ``need_depth``). Returns (rgb, depth as float32 or None)."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"rgb must be (H, W, 3), got shape {rgb.shape}")
    if rgb.dtype != np.uint8:
        raise ValueError(f"rgb must be uint8 (0-255), got {rgb.dtype}")
    if depth is None:
        if need_depth:
            raise ValueError("this segmenter needs depth: pass the (H, W) float32 depth image in metres")
        return rgb, None
    depth = np.asarray(depth)
    if depth.shape != rgb.shape[:2]:
        raise ValueError(f"depth must be (H, W) = {rgb.shape[:2]} like rgb, got shape {depth.shape}")
    if not np.issubdtype(depth.dtype, np.floating):
        raise ValueError(f"depth must be float metres, got {depth.dtype} (convert e.g. uint16 millimetres first)")
    return rgb, depth.astype(np.float32, copy=False)


def check_batch(rgb: np.ndarray, depth: np.ndarray | None, need_depth: bool,
                name: str) -> tuple[np.ndarray, np.ndarray | None]:
    """Validate a batch: rgb (B, H, W, 3) uint8, depth (B, H, W) float metres (None allowed
    unless ``need_depth``; segmenter ``name`` is named in the error). Returns them as arrays."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 4 or rgb.shape[-1] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"rgb must be (B, H, W, 3) uint8, got shape {rgb.shape} dtype {rgb.dtype}")
    if depth is None:
        if need_depth:
            raise ValueError(f"{name} needs depth: pass the (B, H, W) float32 depth images in metres")
        return rgb, None
    depth = np.asarray(depth)
    if depth.shape != rgb.shape[:3] or not np.issubdtype(depth.dtype, np.floating):
        raise ValueError(f"depth must be (B, H, W) = {rgb.shape[:3]} float metres, got shape {depth.shape} "
                         f"dtype {depth.dtype}")
    return rgb, depth


def check_label_image(name: str, image: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray:
    """Validate an (H, W) integer image (``semantic`` / ``instance``) of the frame's size."""
    if image is None:
        raise ValueError(f"this segmenter needs the ground-truth {name!r} image: pass {name}=obs['{name}'] "
                         f"(the env's {name} observation, (H, W) int ids)")
    image = np.asarray(image)
    if image.shape != shape:
        raise ValueError(f"{name} must be (H, W) = {shape}, got shape {image.shape}")
    if not np.issubdtype(image.dtype, np.integer):
        raise ValueError(f"{name} must hold integer ids, got {image.dtype}")
    return image


class Segmenter(ABC):
    """Base class. Subclasses set ``name``, ``class_names`` and implement ``segment``."""

    name: str = ""
    class_names: tuple[str, ...] = ()
    needs_depth: bool = False       # segment() raises without depth
    needs_semantic: bool = False    # segment() needs the ground-truth semantic image
    privileged: tuple[str, ...] = ()  # privileged data the agent hands it (agent.contract: camera_pose, instance)

    @property
    def num_classes(self) -> int:
        return len(self.class_names)

    def __call__(self, rgb: np.ndarray, depth: np.ndarray | None = None, **kwargs) -> np.ndarray:
        return self.segment(rgb, depth, **kwargs)

    @abstractmethod
    def segment(self, rgb: np.ndarray, depth: np.ndarray | None = None, **kwargs) -> np.ndarray:
        """rgb (H, W, 3) uint8, depth (H, W) float32 metres -> logits (H, W, K) float32."""

    def segment_batch(self, rgb: np.ndarray, depth: np.ndarray | None = None, **kwargs) -> np.ndarray:
        """rgb (B, H, W, 3), depth (B, H, W) -> logits (B, H, W, K). Keyword images (semantic,
        instance) are (B, H, W) and ``poses`` is (B, 4, 4); the default loops over frames."""
        rgb = np.asarray(rgb)
        if rgb.ndim != 4:
            raise ValueError(f"segment_batch needs rgb of shape (B, H, W, 3), got {rgb.shape}")
        poses = kwargs.pop("poses", None)
        out = []
        for i in range(len(rgb)):
            kw = {k: (None if v is None else v[i]) for k, v in kwargs.items()}
            if poses is not None:
                kw["pose"] = poses[i]
            out.append(self.segment(rgb[i], None if depth is None else depth[i], **kw))
        return np.stack(out) if out else np.zeros((0, *rgb.shape[1:3], self.num_classes), np.float32)


class BatchSegmenter(Segmenter):
    """A segmenter whose work is done a batch at a time: ``segment`` runs ``segment_batch`` on
    one frame (subclasses implement ``segment_batch`` and call ``check_batch``)."""

    def segment(self, rgb: np.ndarray, depth: np.ndarray | None = None, **_unused) -> np.ndarray:
        """rgb (H, W, 3) uint8, depth (H, W) float32 metres (0 = invalid) -> logits (H, W, K)
        float32. Extra keywords (semantic, instance, pose) are ignored."""
        rgb, depth = check_frame(rgb, depth, need_depth=self.needs_depth)
        return self.segment_batch(rgb[None], None if depth is None else depth[None])[0]
