"""Camera-like training augmentation of a segmenter's rgb batches (the ``train`` keys
``exposure_ev``, ``white_balance``, ``tint``, ``gamma``, ``vignette``, ``motion_blur_*``,
``shot_noise`` and ``jpeg_*``; ``eval.sections.TrainConfig``), so the networks stop relying on
the renderer's exact colours and clean pixels.

Each lever is a pure function of explicit parameters (``exposure``, ``white_balance_gains``,
``tone``, ``vignetting``, ``motion_blur``, ``shot_noise``, ``jpeg``) plus ``camera_levers`` /
``jpeg_lever``, which draw the parameters from the trainer's generator. A lever at its default
(0) draws nothing, so runs without it keep their augmentation stream bit for bit.

Images are (B, 3, H, W) float tensors in [0, 1] (sRGB-encoded, as rendered).
"""
from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

from calnav.eval.sections import TrainConfig

MOTION_BLUR_MIN_PX = 2.0      # the shortest motion-blur streak drawn, pixels


def exposure(rgb: torch.Tensor, ev: torch.Tensor) -> torch.Tensor:
    """``rgb`` scaled by 2 ** ``ev`` (ev: (B,) stops), clipped to [0, 1]."""
    return (rgb * torch.pow(2.0, ev).view(-1, 1, 1, 1)).clamp(0.0, 1.0)


def white_balance_gains(temperature: torch.Tensor, tint: torch.Tensor) -> torch.Tensor:
    """(B, 3) per-channel gains: ``temperature`` > 0 warms (red up, blue down by exp(+-t)),
    ``tint`` > 0 turns green (green up by exp(u), red and blue down by exp(-u / 2)); both (B,)."""
    t, u = temperature.view(-1, 1), tint.view(-1, 1)
    return torch.exp(torch.cat([t - u / 2, u, -t - u / 2], dim=1))


def tone(rgb: torch.Tensor, log2_gamma: torch.Tensor) -> torch.Tensor:
    """The tone curve ``rgb ** 2 ** log2_gamma`` (B,): > 0 darkens mid-tones, < 0 lifts them."""
    return rgb.clamp(0.0, 1.0).pow(torch.pow(2.0, log2_gamma).view(-1, 1, 1, 1))


def vignetting(rgb: torch.Tensor, strength: torch.Tensor) -> torch.Tensor:
    """``rgb`` darkened by 1 - strength * r ** 2 (strength (B,); r: distance from the centre,
    1 at the corners)."""
    h, w = rgb.shape[-2:]
    y = torch.linspace(-1.0, 1.0, h, device=rgb.device).view(h, 1)
    x = torch.linspace(-1.0, 1.0, w, device=rgb.device).view(1, w)
    r2 = (x ** 2 + y ** 2) / 2.0
    return rgb * (1.0 - strength.view(-1, 1, 1, 1) * r2)


def motion_blur_kernel(length_px: float, angle_rad: float) -> torch.Tensor:
    """(k, k) kernel summing to 1: a line of ``length_px`` pixels through the centre at
    ``angle_rad``, its samples splatted bilinearly."""
    r = int(math.ceil(length_px / 2))
    k = torch.zeros(2 * r + 1, 2 * r + 1, dtype=torch.float64)
    n = max(2, int(math.ceil(length_px)) * 2)
    for s in np.linspace(-length_px / 2, length_px / 2, n):
        x, y = r + s * math.cos(angle_rad), r + s * math.sin(angle_rad)
        x0, y0 = int(math.floor(x)), int(math.floor(y))
        fx, fy = x - x0, y - y0
        for dx, dy, wgt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
            if 0 <= x0 + dx <= 2 * r and 0 <= y0 + dy <= 2 * r:
                k[y0 + dy, x0 + dx] += wgt
    return (k / k.sum()).float()


def motion_blur(rgb: torch.Tensor, kernel: torch.Tensor) -> torch.Tensor:
    """(B, C, H, W) images convolved with the (k, k) ``kernel`` (edges replicated)."""
    r = kernel.shape[0] // 2
    c = rgb.shape[1]
    out = F.pad(rgb, (r, r, r, r), mode="replicate")
    return F.conv2d(out, kernel.to(rgb).view(1, 1, *kernel.shape).expand(c, 1, -1, -1), groups=c)


def shot_noise(rgb: torch.Tensor, noise: torch.Tensor, std_at_white: torch.Tensor) -> torch.Tensor:
    """Signal-dependent noise: ``noise`` (standard normal, rgb's shape) * std, std = ``std_at_white``
    (B,) * sqrt(rgb) (photon noise: variance proportional to the signal), clipped to [0, 1]."""
    return (rgb + noise * std_at_white.view(-1, 1, 1, 1) * rgb.clamp(min=0.0).sqrt()).clamp(0.0, 1.0)


def jpeg(rgb: torch.Tensor, quality: list[int]) -> torch.Tensor:
    """Each image JPEG-compressed at its ``quality`` (0-100, cv2) and decoded (via uint8)."""
    import cv2

    out = rgb.clone()
    for i, q in enumerate(quality):
        img = (rgb[i].permute(1, 2, 0).clamp(0, 1) * 255.0).round().to(torch.uint8).cpu().numpy()
        ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(img[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(q)])
        if not ok:
            raise RuntimeError(f"cv2.imencode failed to encode a {img.shape} image as JPEG")
        dec = cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1].copy()
        out[i] = torch.from_numpy(dec).to(rgb).permute(2, 0, 1) / 255.0
    return out


def _uniform(gen: torch.Generator, lo: float, hi: float, n: int) -> torch.Tensor:
    return lo + (hi - lo) * torch.rand(n, generator=gen)


def camera_levers(rgb: torch.Tensor, gen: torch.Generator, cfg: TrainConfig) -> torch.Tensor:
    """Vignetting, exposure, white balance, motion blur, tone curve and shot noise, each drawn
    per image from ``gen`` only when its key is on (motion blur: one streak per batch, applied
    to a ``motion_blur_prob`` share of the images)."""
    b, dev = rgb.shape[0], rgb.device
    if cfg.vignette > 0:
        rgb = vignetting(rgb, _uniform(gen, 0.0, cfg.vignette, b).to(dev))
    if cfg.exposure_ev > 0:
        rgb = exposure(rgb, _uniform(gen, -cfg.exposure_ev, cfg.exposure_ev, b).to(dev))
    if cfg.white_balance > 0 or cfg.tint > 0:
        t = _uniform(gen, -cfg.white_balance, cfg.white_balance, b) if cfg.white_balance > 0 else torch.zeros(b)
        u = _uniform(gen, -cfg.tint, cfg.tint, b) if cfg.tint > 0 else torch.zeros(b)
        rgb = (rgb * white_balance_gains(t, u).to(dev).view(b, 3, 1, 1)).clamp(0.0, 1.0)
    if cfg.motion_blur_prob > 0:
        length = float(_uniform(gen, MOTION_BLUR_MIN_PX, max(cfg.motion_blur_px, MOTION_BLUR_MIN_PX), 1))
        angle = float(_uniform(gen, 0.0, math.pi, 1))
        pick = (torch.rand(b, generator=gen) < cfg.motion_blur_prob).to(dev)
        rgb = torch.where(pick[:, None, None, None], motion_blur(rgb, motion_blur_kernel(length, angle)), rgb)
    if cfg.gamma > 0:
        rgb = tone(rgb, _uniform(gen, -cfg.gamma, cfg.gamma, b).to(dev))
    if cfg.shot_noise > 0:
        noise = torch.randn(rgb.shape, generator=gen).to(dev)
        rgb = shot_noise(rgb, noise, _uniform(gen, 0.0, cfg.shot_noise / 255.0, b).to(dev))
    return rgb


def jpeg_lever(rgb: torch.Tensor, gen: torch.Generator, cfg: TrainConfig) -> torch.Tensor:
    """A ``jpeg_prob`` share of the images JPEG-compressed at a quality drawn uniformly from
    ``jpeg_quality`` (nothing drawn when ``jpeg_prob`` is 0)."""
    if cfg.jpeg_prob <= 0:
        return rgb
    lo, hi = cfg.jpeg_quality
    b = rgb.shape[0]
    pick = torch.rand(b, generator=gen) < cfg.jpeg_prob
    quality = torch.randint(int(lo), int(hi) + 1, (b,), generator=gen)
    idx = torch.nonzero(pick).flatten()
    if len(idx) == 0:
        return rgb
    out = rgb.clone()
    out[idx.to(rgb.device)] = jpeg(rgb[idx.to(rgb.device)], [int(quality[i]) for i in idx])
    return out
