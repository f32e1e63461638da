"""Compact CPU segmentation networks: the calnav stand-ins for Segformer (RGB) and ESANet (RGB-D).

Architecture (``SegNet``), all convolutions padded so any input size works:

- RGB encoder, MobileNet-v1 style depthwise-separable blocks (3x3 depthwise + 1x1 pointwise,
  BatchNorm, ReLU; residual when shape is kept). Output strides 2 (stem), 4, 8, 16, 32.
- Global context: the stride-32 features plus their global average (a one-level pyramid
  pooling), so small rooms' whole-image layout informs every pixel.
- Decoder: light FPN. 1x1 laterals project strides 32, 16, 8, 4 to ``decoder_width``
  channels; top-down bilinear upsampling + add; one depthwise-separable block smooths the
  stride-4 map; a 1x1 classifier gives K logits that are bilinearly upsampled to the input.
- RGB-D (``in_depth=True``, ESANet-like two-branch encoder): a depth branch of
  ``depth_ratio`` times the RGB width (half by default) runs in parallel on (depth / depth_scale_m, valid mask); after every stage its features are
  projected (1x1 conv + BN) and added to the RGB branch (ESANet fuses the same way, with
  squeeze-and-excitation weights we leave out for speed).

Inputs: rgb (B, 3, H, W) float in [0, 1]; depth (B, 1, H, W) float metres, 0 = invalid.
Output: logits (B, K, H, W) float32.

``fuse_batchnorm`` folds every BatchNorm into the preceding convolution for inference (eval
mode only): one fewer pass over every feature map.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F
from torch import nn

RGB_MEAN = (0.5, 0.5, 0.5)          # rgb normalisation: (x - mean) / std on [0, 1] values
RGB_STD = (0.25, 0.25, 0.25)
DEPTH_SCALE_M = 5.0                 # depth input is depth / DEPTH_SCALE_M (the sensor's max range)


@dataclass
class NetSpec:
    """Architecture hyper-parameters (stored in the weights file so loading rebuilds the net).

    stem: stride-2 stem channels. stages: (channels, blocks) of the stride 4, 8, 16, 32 stages
    (the first block of each stage has stride 2). decoder_width: FPN channels. num_classes: K.
    in_depth: RGB-D two-branch encoder. depth_ratio: depth-branch width relative to the RGB
    branch (weights saved before the key existed used 0.5, the default).
    """

    num_classes: int = 18
    in_depth: bool = False
    stem: int = 16
    stages: tuple[tuple[int, int], ...] = ((32, 2), (64, 3), (128, 4), (160, 2))
    decoder_width: int = 64
    depth_ratio: float = 0.5

    def to_dict(self) -> dict:
        d = asdict(self)
        d["stages"] = [list(s) for s in self.stages]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "NetSpec":
        d = dict(d)
        d["stages"] = tuple(tuple(int(v) for v in s) for s in d["stages"])
        return cls(**d)


def conv_bn(cin: int, cout: int, k: int = 1, stride: int = 1, groups: int = 1, act: bool = True) -> nn.Sequential:
    """Conv (no bias) + BatchNorm (+ ReLU). Padding k // 2 keeps size / stride."""
    layers: list[nn.Module] = [nn.Conv2d(cin, cout, k, stride, k // 2, groups=groups, bias=False), nn.BatchNorm2d(cout)]
    if act:
        layers.append(nn.ReLU(inplace=True))
    return nn.Sequential(*layers)


class DSBlock(nn.Module):
    """Depthwise 3x3 (stride s) + pointwise 1x1, each with BN + ReLU; residual if shapes match."""

    def __init__(self, cin: int, cout: int, stride: int = 1):
        super().__init__()
        self.dw = conv_bn(cin, cin, 3, stride, groups=cin)
        self.pw = conv_bn(cin, cout, 1)
        self.residual = stride == 1 and cin == cout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.pw(self.dw(x))
        return x + y if self.residual else y


def _stage(cin: int, cout: int, blocks: int) -> nn.Sequential:
    return nn.Sequential(DSBlock(cin, cout, 2), *[DSBlock(cout, cout, 1) for _ in range(blocks - 1)])


class Encoder(nn.Module):
    """Stem (stride 2) + four stages; returns features at strides 4, 8, 16, 32."""

    def __init__(self, in_ch: int, stem: int, stages: tuple[tuple[int, int], ...]):
        super().__init__()
        self.stem = conv_bn(in_ch, stem, 3, 2)
        chans = [stem] + [c for c, _ in stages]
        self.stages = nn.ModuleList(_stage(chans[i], chans[i + 1], n) for i, (_, n) in enumerate(stages))
        self.channels = chans[1:]


class SegNet(nn.Module):
    """See the module docstring. forward(rgb (B,3,H,W) in [0,1], depth (B,1,H,W) m or None)."""

    def __init__(self, spec: NetSpec):
        super().__init__()
        self.spec = spec
        self.rgb = Encoder(3, spec.stem, spec.stages)
        self.register_buffer("mean", torch.tensor(RGB_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(RGB_STD).view(1, 3, 1, 1), persistent=False)
        if spec.in_depth:
            dstages = tuple((max(8, int(c * spec.depth_ratio)), n) for c, n in spec.stages)
            self.depth = Encoder(2, max(8, int(spec.stem * spec.depth_ratio)), dstages)
            self.fuse = nn.ModuleList(conv_bn(dc, c, 1, act=False)
                                      for dc, c in zip(self.depth.channels, self.rgb.channels))
        d = spec.decoder_width
        chans = self.rgb.channels
        self.context = conv_bn(chans[-1], d, 1)
        self.laterals = nn.ModuleList(conv_bn(c, d, 1, act=False) for c in chans)
        self.smooth = DSBlock(d, d, 1)
        self.classifier = nn.Conv2d(d, spec.num_classes, 1)

    def forward(self, rgb: torch.Tensor, depth: torch.Tensor | None = None) -> torch.Tensor:
        h, w = rgb.shape[-2:]
        x = (rgb - self.mean) / self.std
        x = self.rgb.stem(x)
        if self.spec.in_depth:
            if depth is None:
                raise ValueError("this RGB-D network needs a depth input")
            valid = (depth > 0).to(depth.dtype)
            y = self.depth.stem(torch.cat([depth / DEPTH_SCALE_M, valid], dim=1))
        feats = []
        for i, stage in enumerate(self.rgb.stages):
            x = stage(x)
            if self.spec.in_depth:
                y = self.depth.stages[i](y)
                x = x + self.fuse[i](y)
            feats.append(x)
        # top-down FPN; the deepest level also gets the global context (mean over the image)
        top = self.laterals[-1](feats[-1]) + self.context(feats[-1].mean(dim=(2, 3), keepdim=True))
        for lat, f in zip(reversed(self.laterals[:-1]), reversed(feats[:-1])):
            top = lat(f) + F.interpolate(top, size=f.shape[-2:], mode="bilinear", align_corners=False)
        out = self.classifier(self.smooth(F.relu(top)))
        return F.interpolate(out, size=(h, w), mode="bilinear", align_corners=False)


def _fold(conv: nn.Conv2d, bn: nn.BatchNorm2d) -> nn.Conv2d:
    """A conv with bias equal to conv followed by bn (eval statistics)."""
    scale = bn.weight / torch.sqrt(bn.running_var + bn.eps)
    fused = nn.Conv2d(conv.in_channels, conv.out_channels, conv.kernel_size, conv.stride, conv.padding,
                      conv.dilation, conv.groups, bias=True)
    with torch.no_grad():
        fused.weight.copy_(conv.weight * scale.view(-1, 1, 1, 1))
        bias = conv.bias if conv.bias is not None else torch.zeros_like(bn.running_mean)
        fused.bias.copy_((bias - bn.running_mean) * scale + bn.bias)
    return fused


def fuse_batchnorm(module: nn.Module) -> nn.Module:
    """Fold every Conv2d -> BatchNorm2d pair inside ``nn.Sequential`` containers (in place);
    returns the module. Only valid in eval mode (uses running statistics)."""
    for name, child in module.named_children():
        if isinstance(child, nn.Sequential) and len(child) >= 2 and isinstance(child[0], nn.Conv2d) \
                and isinstance(child[1], nn.BatchNorm2d):
            layers = [_fold(child[0], child[1]), *list(child)[2:]]
            setattr(module, name, nn.Sequential(*layers))
        else:
            fuse_batchnorm(child)
    return module


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
