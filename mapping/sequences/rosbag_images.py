"""Decoding the images of a ROS bag: ``sensor_msgs/Image`` (raw) and ``sensor_msgs/CompressedImage``
(image_transport's ``compressed`` plugin: JPEG / PNG; ``compressed_depth`` plugin: a 12-byte
header then a PNG) into calnav's arrays.

- colour: raw ``rgb8``, ``bgr8``, ``rgba8``, ``bgra8``, ``mono8``; compressed JPEG / PNG ->
  (H, W, 3) uint8 RGB.
- depth: raw ``16UC1`` / ``mono16`` (millimetres, REP 118) or ``32FC1`` (metres);
  ``compressedDepth`` PNG of either; a 16-bit ``compressed`` PNG (millimetres) -> (h, w)
  float32 metres, 0 = invalid (millimetres through ``readers.depth_from_raw``: the
  ``sequence`` keys ``depth_scale``, ``invalid_depth_raw``, ``depth_trunc_m`` apply as on a
  folder; metres: NaN, inf and <= 0 invalid, ``depth_trunc_m`` applies).
- labels: raw ``mono16`` / ``16UC1`` (class id + 1, 0 = void, as ``semantic/N.png``) or a
  16-bit PNG -> (h, w) int64 class ids, -1 = void.

``compressedDepth`` layout (compressed_depth_image_transport ``codec.cpp``): ``format`` is
``"<encoding>; compressedDepth png"`` (older: ``"<encoding>; compressedDepth"``), ``data`` is a
``ConfigHeader`` {int32 format; float32 depthParam[2]} (12 bytes, little-endian) then the PNG.
For ``16UC1`` the PNG holds the millimetres; for ``32FC1`` it holds quantised inverse depth
v (uint16) with depth = depthParam[0] / (v - depthParam[1]) metres, v = 0 invalid. The ``rvl``
compression of ROS 2's plugin is not read (one-line error).
"""
from __future__ import annotations

import cv2
import numpy as np

from calnav.mapping.sequences.readers import SEMANTIC_OFFSET, SequenceConfig, depth_from_raw

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
IMAGE_TYPES = (IMAGE, COMPRESSED)
COLOR_ENCODINGS = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1}   # encoding -> channels
MM_ENCODINGS = ("16UC1", "mono16")    # uint16 depth, millimetres (REP 118)
METRE_ENCODINGS = ("32FC1",)          # float32 depth, metres (REP 118)
DEPTH_HEADER_BYTES = 12               # compressed_depth ConfigHeader: int32 + 2 float32
COLOR_SUPPORTED = "raw rgb8, bgr8, rgba8, bgra8, mono8, or compressed jpeg / png"
DEPTH_SUPPORTED = "raw 16UC1 / mono16 (millimetres) or 32FC1 (metres), compressedDepth png, or a 16-bit png"
LABEL_SUPPORTED = "raw mono16 / 16UC1 (class id + 1), or a 16-bit png"


def _raw_array(msg, dtype: np.dtype, channels: int) -> np.ndarray:
    """(h, w[, c]) view of a raw Image's pixels (row stride ``step``; ``is_bigendian``)."""
    dt = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    row = w * channels * dt.itemsize
    data = np.asarray(msg.data, np.uint8)
    if step < row or data.size < step * h:
        raise ValueError(f"a {w}x{h} {msg.encoding} image holds {data.size} bytes with step {step}; "
                         f"expected at least {row} bytes a row (truncated message?)")
    px = data[:step * h].reshape(h, step)[:, :row].copy().view(dt)
    return px.reshape((h, w, channels) if channels > 1 else (h, w)).astype(dt.newbyteorder("="), copy=False)


def _imdecode(data, flags: int, what: str) -> np.ndarray:
    img = cv2.imdecode(np.frombuffer(memoryview(np.ascontiguousarray(data, np.uint8)), np.uint8), flags)
    if img is None:
        raise ValueError(f"cannot decode the compressed {what} image")
    return img


def image_format(msg, msgtype: str) -> str:
    """The image's encoding (raw) or ``format`` (compressed), as the bag states it."""
    return msg.encoding if msgtype == IMAGE else msg.format


def color_rgb(msg, msgtype: str) -> np.ndarray:
    """(H, W, 3) uint8 RGB of a colour image message; ValueError for another encoding."""
    if msgtype == COMPRESSED:
        if "compressedDepth" in msg.format:
            raise ValueError(f"format {msg.format!r} is a depth image; the colour topic needs {COLOR_SUPPORTED}")
        img = _imdecode(msg.data, cv2.IMREAD_UNCHANGED, "colour")
        if img.dtype != np.uint8:
            raise ValueError(f"compressed colour image {msg.format!r} is {img.dtype}; expected 8-bit colour")
        if img.ndim == 2:
            return cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
        return cv2.cvtColor(img, cv2.COLOR_BGRA2RGB if img.shape[2] == 4 else cv2.COLOR_BGR2RGB)
    enc = msg.encoding
    if enc not in COLOR_ENCODINGS:
        raise ValueError(f"colour encoding {enc!r} is not supported; supported: {COLOR_SUPPORTED}")
    px = _raw_array(msg, np.uint8, COLOR_ENCODINGS[enc])
    if enc == "rgb8":
        return px
    code = {"bgr8": cv2.COLOR_BGR2RGB, "rgba8": cv2.COLOR_RGBA2RGB, "bgra8": cv2.COLOR_BGRA2RGB,
            "mono8": cv2.COLOR_GRAY2RGB}[enc]
    return cv2.cvtColor(px, code)


def _compressed_depth(msg) -> tuple[np.ndarray, str]:
    """(decoded PNG, original encoding) of a ``compressedDepth`` message."""
    encoding, _, rest = msg.format.partition(";")
    encoding, rest = encoding.strip(), rest.strip()
    if rest not in ("compressedDepth", "compressedDepth png"):
        raise ValueError(f"compressedDepth format {msg.format!r} is not supported (only png); "
                         f"supported: {DEPTH_SUPPORTED}")
    data = np.asarray(msg.data, np.uint8)
    if data.size <= DEPTH_HEADER_BYTES:
        raise ValueError(f"compressedDepth image of {data.size} bytes holds no PNG after its {DEPTH_HEADER_BYTES}-byte header")
    png = _imdecode(data[DEPTH_HEADER_BYTES:], cv2.IMREAD_UNCHANGED, "depth")
    if png.ndim != 2 or png.dtype != np.uint16:
        raise ValueError(f"compressedDepth PNG is {png.dtype} with shape {png.shape}; expected single-channel 16-bit")
    return png, encoding


def depth_metres(msg, msgtype: str, cfg: SequenceConfig) -> np.ndarray:
    """(h, w) float32 metres (0 = invalid) of a depth image message (see the module docstring)."""
    if msgtype == COMPRESSED:
        if "compressedDepth" in msg.format:
            png, encoding = _compressed_depth(msg)
            if encoding in MM_ENCODINGS:
                return depth_from_raw(png, cfg)
            if encoding not in METRE_ENCODINGS:
                raise ValueError(f"compressedDepth encoding {encoding!r} is not a depth encoding; supported: {DEPTH_SUPPORTED}")
            quant_a, quant_b = np.frombuffer(np.asarray(msg.data, np.uint8)[4:DEPTH_HEADER_BYTES].tobytes(), "<f4")
            with np.errstate(divide="ignore", invalid="ignore"):
                depth = np.float32(quant_a) / (png.astype(np.float32) - np.float32(quant_b))
            depth[png == 0] = 0.0
            return _metres(depth, cfg)
        png = _imdecode(msg.data, cv2.IMREAD_UNCHANGED, "depth")
        if png.ndim != 2 or png.dtype != np.uint16:
            raise ValueError(f"compressed depth {msg.format!r} decodes to {png.dtype} with shape {png.shape}; "
                             f"supported: {DEPTH_SUPPORTED}")
        return depth_from_raw(png, cfg)
    if msg.encoding in MM_ENCODINGS:
        return depth_from_raw(_raw_array(msg, np.uint16, 1), cfg)
    if msg.encoding in METRE_ENCODINGS:
        return _metres(_raw_array(msg, np.float32, 1), cfg)
    raise ValueError(f"depth encoding {msg.encoding!r} is not supported; supported: {DEPTH_SUPPORTED}")


def _metres(depth: np.ndarray, cfg: SequenceConfig) -> np.ndarray:
    """float32 metres with NaN / inf / <= 0 (and beyond ``depth_trunc_m`` when > 0) set to 0."""
    depth = np.asarray(depth, np.float32)
    bad = ~np.isfinite(depth) | (depth <= 0)
    if cfg.depth_trunc_m > 0:
        bad |= depth > cfg.depth_trunc_m
    return np.where(bad, np.float32(0.0), depth)


def label_ids(msg, msgtype: str) -> np.ndarray:
    """(h, w) int64 class ids (-1 = void) of a label image message."""
    if msgtype == COMPRESSED:
        raw = _imdecode(msg.data, cv2.IMREAD_UNCHANGED, "label")
        if raw.ndim != 2 or raw.dtype != np.uint16:
            raise ValueError(f"label image {msg.format!r} decodes to {raw.dtype} with shape {raw.shape}; "
                             f"supported: {LABEL_SUPPORTED}")
    elif msg.encoding in MM_ENCODINGS:
        raw = _raw_array(msg, np.uint16, 1)
    else:
        raise ValueError(f"label encoding {msg.encoding!r} is not supported; supported: {LABEL_SUPPORTED}")
    return raw.astype(np.int64) - SEMANTIC_OFFSET
