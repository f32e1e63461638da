"""`calnav train-segmenter`: train ``learned_rgb`` / ``learned_rgbd`` on simulator frames.

    calnav train-segmenter --segmenter learned_rgb [--config configs/segmenter.yaml] [KEY=VALUE ...]
                           [--output agent/weights/learned_rgb.pt] [--resume]

Data: ``data.frames`` frames rendered from the *train* split only (``eval.segmenter.data``,
cached on disk); ``train.val_frames`` val-split frames are scored after every epoch.
Training: from a random initialisation, or fine-tuning from a weight file (``train.init_weights``:
the same model, calnav's classes in order, the train.net_* shape; checked before any frame is
rendered, and named by its sha256 in the checkpoint key and the card), cross-entropy (void
ignored, optional inverse-log-frequency class weights), AdamW with a one-cycle learning-rate
schedule, on-the-fly augmentation (brightness, contrast, per-channel colour gain, optional
camera-like levers: vignetting, exposure, white balance, motion blur, tone curve, shot noise
(``eval.segmenter.photometric``), Gaussian rgb noise, optional Gaussian blur, optional JPEG
compression, multiplicative depth noise, optional depth dropout, horizontal flips), all drawn
from generators seeded by (run.seed, epoch), so a resumed run is bit-identical to an uninterrupted
one on the same machine and thread count.

Checkpoints (model, optimiser, schedule, epoch, RNG states, history) are written after every
epoch to ``cache_dir()/segtrain/<model>_<key>.ckpt`` (``key`` hashes the config); ``--resume``
continues from it. The result is a weight file (fp16 state dict, see ``agent.segmenters.learned``)
plus a JSON card ``<output>.json`` with the command, seed, data size, wall time and metrics.
"""
from __future__ import annotations

import hashlib
import json
import math
import platform
import shlex
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from calnav.agent.segmenters.base import resolve_device, segmenter_device
from calnav.agent.segmenters.learned import (LEARNED_MODELS, check_weights, default_weights_path, load_weights,
                                             save_weights)
from calnav.agent.segmenters.network import NetSpec, SegNet, count_parameters
from calnav.common.atomic import atomic_path, undefined_as_null, write_json_atomic
from calnav.eval.config import Config, to_dict
from calnav.eval.inputs import sha256_file
from calnav.eval.results_dir import check_output_file
from calnav.eval.sections import TrainConfig
from calnav.eval.segmenter.data import VAL_SEED_OFFSET, SegData, load_or_render
from calnav.eval.segmenter.photometric import camera_levers, jpeg_lever
from calnav.mapping.metrics import CalibrationStats
from dataclasses import dataclass
from typing import Literal
from calnav.eval.arguments import REQUIRED, Command, arg
from calnav.eval.config import SEGMENTER_SECTIONS
from calnav.eval.segmenter.data import segmenter_configs

ENET_C = 1.02                 # ENet class weights 1 / ln(c + frequency)
LOSS_EMA = 0.95               # smoothing of the loss shown in the progress bar
EVAL_BATCH = 32               # frames per forward pass when scoring
CKPT_VERSION = 1
AUG_SEED_STRIDE = 1_000_003   # augmentation seed = run.seed * this + epoch (distinct per (seed, epoch))


# ------------------------------------------------------------------------------ helpers
def class_weights(labels: np.ndarray, k: int, mode: str, power: float = 1.0) -> torch.Tensor | None:
    """(K,) cross-entropy weights from label frequencies f (void excluded):
    (1 / ln(ENET_C + f)) ** power for ``inv_log``, None for ``none``."""
    if mode == "none":
        return None
    counts = np.bincount(labels[labels >= 0].astype(np.int64).ravel(), minlength=k)[:k].astype(np.float64)
    freq = counts / max(counts.sum(), 1.0)
    return torch.tensor((1.0 / np.log(ENET_C + freq)) ** power, dtype=torch.float32)


def to_tensors(data: SegData, idx: np.ndarray, device: torch.device, need_depth: bool):
    """(rgb (B, 3, H, W) float [0, 1] channels-last, depth (B, 1, H, W) float m or None,
    labels (B, H, W) int64, -1 void) for frames ``idx``."""
    rgb = torch.from_numpy(data.rgb[idx]).to(device).permute(0, 3, 1, 2).float().div_(255.0)
    depth = torch.from_numpy(data.depth[idx].astype(np.float32)).to(device)[:, None] if need_depth else None
    labels = torch.from_numpy(data.labels[idx].astype(np.int64)).to(device)
    return rgb, depth, labels


def augment(rgb: torch.Tensor, depth: torch.Tensor | None, labels: torch.Tensor, gen: torch.Generator,
            cfg: TrainConfig, max_depth_m: float):
    """Photometric + sensor-noise augmentation and flips (random numbers from ``gen``, CPU)."""
    b = rgb.shape[0]

    def uniform(lo: float, hi: float, *shape: int) -> torch.Tensor:
        return (lo + (hi - lo) * torch.rand(shape, generator=gen)).to(rgb.device)

    gain = uniform(1 - cfg.brightness, 1 + cfg.brightness, b, 1, 1, 1) * uniform(1 - cfg.colour, 1 + cfg.colour, b, 3, 1, 1)
    contrast = uniform(1 - cfg.contrast, 1 + cfg.contrast, b, 1, 1, 1)
    mean = rgb.mean(dim=(1, 2, 3), keepdim=True)
    rgb = (rgb - mean) * contrast + mean
    rgb = rgb * gain
    rgb = camera_levers(rgb, gen, cfg)   # each draws only when on (the stream of runs without them is unchanged)
    noise = torch.randn(rgb.shape, generator=gen).to(rgb.device)
    rgb = (rgb + noise * uniform(0, cfg.rgb_noise_std / 255.0, b, 1, 1, 1)).clamp_(0.0, 1.0)
    if cfg.blur_prob > 0:   # drawn only when enabled: runs without blur keep their augmentation stream
        sigma = float(uniform(0.3, max(cfg.blur_sigma_px, 0.3), 1))
        blurred = gaussian_blur(rgb, sigma)
        pick = (torch.rand(b, generator=gen) < cfg.blur_prob).to(rgb.device)
        rgb = torch.where(pick[:, None, None, None], blurred, rgb)
    rgb = jpeg_lever(rgb, gen, cfg)      # last: compression sees the noise a camera's encoder sees
    if depth is not None:
        valid = depth > 0
        dn = torch.randn(depth.shape, generator=gen).to(depth.device)
        depth = depth * (1 + dn * uniform(0, cfg.depth_noise_std, b, 1, 1, 1))
        depth = torch.where(valid & (depth <= max_depth_m), depth, torch.zeros_like(depth))
        if cfg.depth_dropout_prob > 0:   # drawn only when enabled, as for blur
            drop = (torch.rand(b, generator=gen) < cfg.depth_dropout_prob).to(depth.device)
            depth = torch.where(drop[:, None, None, None], torch.zeros_like(depth), depth)
    if cfg.hflip:
        flip = (torch.rand(b, generator=gen) < 0.5).to(rgb.device)
        rgb = torch.where(flip[:, None, None, None], rgb.flip(-1), rgb)
        labels = torch.where(flip[:, None, None], labels.flip(-1), labels)
        if depth is not None:
            depth = torch.where(flip[:, None, None, None], depth.flip(-1), depth)
    return rgb.contiguous(memory_format=torch.channels_last), depth, labels


def gaussian_blur(img: torch.Tensor, sigma: float) -> torch.Tensor:
    """(B, C, H, W) images blurred by a separable Gaussian of std ``sigma`` pixels (radius 2 sigma,
    edges replicated)."""
    r = max(1, int(math.ceil(2 * sigma)))
    x = torch.arange(-r, r + 1, dtype=img.dtype, device=img.device)
    k = torch.exp(-0.5 * (x / sigma) ** 2)
    k = k / k.sum()
    c = img.shape[1]
    out = F.pad(img, (r, r, r, r), mode="replicate")
    out = F.conv2d(out, k.view(1, 1, 1, -1).expand(c, 1, 1, -1), groups=c)
    return F.conv2d(out, k.view(1, 1, -1, 1).expand(c, 1, -1, 1), groups=c)


def confusion_update(conf: np.ndarray, logits: torch.Tensor, labels: torch.Tensor) -> None:
    """Add (K_pred, K_true) counts of one batch (void ignored) to ``conf``."""
    k = conf.shape[0]
    pred = logits.argmax(1).reshape(-1).cpu().numpy()
    y = labels.reshape(-1).cpu().numpy()
    keep = y >= 0
    conf += np.bincount(pred[keep] * k + y[keep], minlength=k * k).reshape(k, k)


def miou_from_confusion(conf: np.ndarray) -> float:
    """Mean IoU over classes present in the labels (columns)."""
    tp = np.diag(conf).astype(np.float64)
    actual, predicted = conf.sum(0), conf.sum(1)
    present = actual > 0
    return float(np.mean(tp[present] / (actual + predicted - tp)[present])) if present.any() else float("nan")


@torch.no_grad()
def score(net: SegNet, data: SegData, device: torch.device, k: int) -> dict[str, float]:
    """Accuracy, mIoU and ECE of ``net`` (eval mode) on ``data``."""
    net.eval()
    stats = CalibrationStats(k)
    for start in range(0, len(data), EVAL_BATCH):
        idx = np.arange(start, min(start + EVAL_BATCH, len(data)))
        rgb, depth, labels = to_tensors(data, idx, device, net.spec.in_depth)
        probs = torch.softmax(net(rgb.contiguous(memory_format=torch.channels_last), depth), dim=1)
        stats.update(probs.permute(0, 2, 3, 1).reshape(-1, k).cpu().numpy(), labels.reshape(-1).cpu().numpy(), -1)
    return {"accuracy": stats.accuracy(), "miou": stats.miou(), "ece": stats.ece(), "mece": stats.mece()}


def initial_state(path: str, model: str, spec: NetSpec) -> tuple[dict[str, torch.Tensor], str]:
    """(float32 state dict, sha256) of the weight file ``path`` a fine-tuning starts from: a
    ``model`` file with calnav's classes in calnav's order and the network ``spec`` (the
    train.net_* keys; the depth-branch width only for learned_rgbd). FileNotFoundError /
    ValueError name the file and what differs."""
    from calnav.envs.semantics import CLASS_NAMES

    file = Path(path)
    check_weights(file, model)   # readable, this model, tensors that fit the file's own spec
    data = load_weights(file, model)
    if list(data["class_names"]) != list(CLASS_NAMES):
        raise ValueError(f"train.init_weights={path}: its classes ({', '.join(data['class_names'])}) are not calnav's "
                         f"in order ({', '.join(CLASS_NAMES)}); fine-tuning keeps the output layer as it is")
    have = NetSpec.from_dict(data["spec"])
    if not spec.in_depth:   # the RGB network has no depth branch: its width ratio is not part of its shape
        have.depth_ratio = spec.depth_ratio
    if have != spec:
        differ = [f"{k} {getattr(have, k)} (train: {getattr(spec, k)})" for k in vars(spec)
                  if getattr(have, k) != getattr(spec, k)]
        raise ValueError(f"train.init_weights={path} holds a network of another shape: {'; '.join(differ)}; set the "
                         "train.net_* keys to the file's")
    return {k: v.float() for k, v in data["state_dict"].items()}, sha256_file(file)


def checkpoint_path(cfg: Config, model: str) -> Path:
    from calnav.envs.scene import cache_dir

    d = to_dict(cfg)
    d["run"].pop("output_dir", None), d["run"].pop("workers", None), d["train"].pop("threads", None)
    d["segmenter"] = {}  # inference settings do not change training
    if cfg.train.init_weights:   # the file's content, not its name: a retrained file never resumes an old run
        d["train"]["init_weights"] = sha256_file(Path(cfg.train.init_weights))
    key = hashlib.sha1(json.dumps([model, d], sort_keys=True).encode()).hexdigest()[:12]
    return cache_dir() / "segtrain" / f"{model}_{key}.ckpt"


def _save_atomic(obj, path: Path) -> None:
    with atomic_path(path) as tmp:
        torch.save(obj, tmp)


# ----------------------------------------------------------------------------- training
def train(cfg: Config, model: str, output: Path | str, resume: bool = False,
          progress: bool = True, command: str = "", stop_after_epoch: int | None = None) -> dict | None:
    """Train ``model`` under ``cfg``; writes ``output`` (weights) and ``output``.json (card).
    Returns the card (a dict). ``stop_after_epoch``: return None after checkpointing that
    epoch (an interrupted run, to be continued with ``resume=True``)."""
    from tqdm import tqdm

    from calnav.envs.semantics import CLASS_NAMES

    if model not in LEARNED_MODELS:
        raise ValueError(f"cannot train {model!r}; trainable models: {', '.join(LEARNED_MODELS)}")
    tc, seed = cfg.train, int(cfg.run.seed)
    device = resolve_device(segmenter_device(cfg.segmenter, cfg.run.device))   # checked, the key named
    if tc.threads > 0:
        torch.set_num_threads(tc.threads)
    output = Path(output)
    k = len(CLASS_NAMES)
    spec = NetSpec(num_classes=k, in_depth=model == "learned_rgbd", stem=tc.net_stem, stages=tuple(tc.net_stages),
                   decoder_width=tc.net_decoder_width, depth_ratio=tc.net_depth_ratio)
    # checked before the frames are rendered (minutes, written to the cache) or anything else is written
    init, init_sha = initial_state(tc.init_weights, model, spec) if tc.init_weights else (None, None)
    t_start = time.perf_counter()
    data = load_or_render(cfg.env, cfg.data, "train", progress=progress, rebalance=True)
    val = (load_or_render(cfg.env, cfg.data, "val", frames=tc.val_frames, seed=cfg.data.seed + VAL_SEED_OFFSET,
                          progress=progress) if tc.val_frames > 0 else None)
    weight = class_weights(data.labels, k, tc.class_weighting, tc.class_weight_power)
    weight = weight.to(device) if weight is not None else None

    torch.manual_seed(seed)
    net = SegNet(spec)
    if init is not None:
        net.load_state_dict(init)
    net = net.to(device=device, memory_format=torch.channels_last)
    opt = torch.optim.AdamW(net.parameters(), lr=tc.lr, weight_decay=tc.weight_decay)
    n, b = len(data), min(tc.batch_size, len(data))
    steps = max(1, n // b)  # drop the last partial batch (BatchNorm needs > 1 sample per channel)
    # + 1: the schedule is stepped after every batch, the last step included
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=tc.lr, total_steps=tc.epochs * steps + 1,
                                                pct_start=tc.warmup_frac)
    ckpt_file = checkpoint_path(cfg, model)
    start_epoch, history, wall_before = 0, [], 0.0
    if resume:
        if ckpt_file.exists():
            # our own file (written below); the optimiser / scheduler states are plain Python objects
            ck = torch.load(ckpt_file, map_location=device, weights_only=False)
            net.load_state_dict(ck["model"])
            opt.load_state_dict(ck["optimizer"])
            sched.load_state_dict(ck["scheduler"])
            torch.set_rng_state(ck["torch_rng"].cpu())
            start_epoch, history, wall_before = ck["epoch"], ck["history"], ck["wall_s"]
            print(f"resuming {model} from {ckpt_file} after epoch {start_epoch}", flush=True)
        else:
            print(f"--resume: no checkpoint at {ckpt_file}; starting from scratch", flush=True)
    t_train = time.perf_counter()
    for epoch in range(start_epoch, tc.epochs):
        net.train()
        perm = np.random.default_rng([seed, epoch]).permutation(n)
        gen = torch.Generator().manual_seed(seed * AUG_SEED_STRIDE + epoch)  # augmentation draws of this epoch
        conf = np.zeros((k, k), dtype=np.int64)
        loss_ema = None
        bar = tqdm(range(steps), desc=f"{model} epoch {epoch + 1}/{tc.epochs}", disable=not progress,
                   mininterval=2.0, dynamic_ncols=True)
        for step in bar:
            idx = np.sort(perm[step * b:(step + 1) * b])
            rgb, depth, labels = to_tensors(data, idx, device, spec.in_depth)
            rgb, depth, labels = augment(rgb, depth, labels, gen, tc, cfg.env.max_depth_m)
            logits = net(rgb, depth)
            # (B, K, H, W) channels-last logits viewed as (B H W, K) rows: log-softmax over the
            # contiguous last axis is ~2x faster on CPU than over dim 1 of an NCHW tensor
            loss = F.cross_entropy(logits.permute(0, 2, 3, 1).reshape(-1, k), labels.reshape(-1), weight=weight,
                                   ignore_index=-1)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            loss_value = loss.detach().item()
            if not math.isfinite(loss_value):
                raise FloatingPointError(f"training diverged (loss {loss_value}) at epoch {epoch + 1} step {step}; "
                                         f"lower train.lr (now {tc.lr})")
            loss_ema = loss_value if loss_ema is None else LOSS_EMA * loss_ema + (1 - LOSS_EMA) * loss_value
            confusion_update(conf, logits.detach(), labels)
            bar.set_postfix(loss=f"{loss_ema:.3f}", miou=f"{miou_from_confusion(conf):.3f}",
                            lr=f"{sched.get_last_lr()[0]:.1e}", refresh=False)  # redrawn every mininterval
        record = {"epoch": epoch + 1, "train_loss": loss_ema, "train_miou": miou_from_confusion(conf),
                  "wall_s": wall_before + time.perf_counter() - t_train}
        if val is not None:
            record.update({f"val_{key}": v for key, v in score(net, val, device, k).items()})
        history.append(record)
        print("  ".join(f"{key} {v:.4g}" if isinstance(v, float) else f"{key} {v}" for key, v in record.items()),
              flush=True)
        _save_atomic({"version": CKPT_VERSION, "model": net.state_dict(), "optimizer": opt.state_dict(),
                      "scheduler": sched.state_dict(), "torch_rng": torch.get_rng_state(), "epoch": epoch + 1,
                      "history": history, "wall_s": record["wall_s"]}, ckpt_file)
        if stop_after_epoch is not None and epoch + 1 >= stop_after_epoch and epoch + 1 < tc.epochs:
            return None
    wall_train = history[-1]["wall_s"] if history else 0.0
    card = {
        "model": model, "command": command or f"calnav train-segmenter --segmenter {model} --output {output}",
        "seed": seed, "train_frames": n, "train_split": "train", "train_scenes": int(len(np.unique(data.scene))),
        "val_frames": len(val) if val is not None else 0, "resolution": list(data.resolution),
        "init_weights": ({"path": tc.init_weights, "sha256": init_sha} if init is not None else None),
        "epochs": tc.epochs, "batch_size": b, "parameters": count_parameters(net),
        "train_wall_s": round(wall_train, 1), "total_wall_s_this_call": round(time.perf_counter() - t_start, 1),
        "device": str(device), "threads": torch.get_num_threads(), "torch": str(torch.__version__),
        "cpu": platform.processor() or platform.machine(), "history": history,
        "config": {"data": asdict(cfg.data), "train": asdict(cfg.train)},
    }
    save_weights(net, output, model, CLASS_NAMES, data.resolution, card)
    card["weights_bytes"] = output.stat().st_size
    card["weights_sha256"] = hashlib.sha256(output.read_bytes()).hexdigest()
    write_json_atomic(output.with_suffix(".json"), undefined_as_null(card), indent=1)
    print(f"wrote {output} ({card['weights_bytes'] / 1e6:.2f} MB) and {output.with_suffix('.json')}", flush=True)
    return card


def main_train_segmenter(args, configs: list[Config]) -> None:
    """``configs``: ``eval.segmenter.data.segmenter_configs(args)``, checked by the preflight."""
    cfg = configs[0]
    output = Path(args.output) if args.output else default_weights_path(args.segmenter)
    check_output_file(output)   # written after training: a bad path fails now, not after 20 minutes
    parts = ["calnav", "train-segmenter", "--segmenter", args.segmenter, "--config", str(args.config), *args.overrides]
    if args.output:
        parts += ["--output", str(args.output)]
    train(cfg, args.segmenter, output, resume=args.resume, command=shlex.join(parts))


@dataclass
class TrainSegmenterArgs:
    """``calnav train-segmenter``'s flags."""

    segmenter: Literal["learned_rgb", "learned_rgbd"] = arg(REQUIRED, "network to train")
    output: str | None = arg(None, "weight file (default: agent/weights/<segmenter>.pt)")
    resume: bool = arg(False, "continue from this config's last epoch checkpoint")


COMMAND = Command(TrainSegmenterArgs, main_train_segmenter, segmenter_configs, config="configs/segmenter.yaml",
                  sections=SEGMENTER_SECTIONS)
