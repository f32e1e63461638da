"""Rerun recordings (``.rrd``): the one place calnav talks to ``rerun-sdk`` (the optional
``[viz]`` extra: ``pip install -e ".[viz]"``; ``make test`` installs it).

Conventions of every calnav recording: ``world`` is z-up metres (the agent's map frame for an
episode, the recording's world for ``calnav map``); cameras are logged with OpenCV axes
(x right, y down, z forward, ``rr.ViewCoordinates.RDF``) as a ``Transform3D`` (world from
camera) plus a ``Pinhole``. A voxel map is logged twice under its entity, so the viewer can
switch between them: ``<entity>/class`` (points coloured by arg-max class, with the class name
as label through the recording's ``AnnotationContext``) and ``<entity>/confidence`` (coloured by
the arg-max probability with matplotlib's viridis, 1/K dark to 1 bright; the probabilities
themselves are logged beside the points as an ``rr.AnyValues`` column ``confidence``, so a
reader gets the numbers back, not only colours).

Reading back (tests, ``calnav view``): ``read_columns(path)`` returns, per entity, the logged
rows as a pyarrow table, from Rerun's own chunk reader (``rerun.chunk.RrdReader``).
"""
from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any, Sequence

import numpy as np

VIZ_HINT = 'needs Rerun: pip install -e ".[viz]" (make test installs it into .venv)'
VOXEL_RADIUS_FRACTION = 0.5   # point radius / voxel size: neighbouring voxels' points touch
# The first bytes of every .rrd file: Rerun's stream FourCC "RRF" plus a format digit (RRF2 since
# Rerun 0.2x); checked before Rerun's reader is asked, so a stray file gets a plain message.
RRD_MAGIC = b"RRF"


def require_rerun(what: str = "--rerun"):
    """The ``rerun`` module, or ValueError naming the install command (a one-line error)."""
    try:
        return importlib.import_module("rerun")
    except ImportError:
        raise ValueError(f"{what} {VIZ_HINT}") from None


def new_recording(application_id: str, path: str | Path, class_names: Sequence[str] = (),
                  palette: np.ndarray | None = None):
    """A ``rr.RecordingStream`` saving to ``path`` (parent directories made), with the class
    names and colours (``palette`` (K, 3) uint8) as a static ``AnnotationContext`` at the root,
    so segmentation images and class-coloured points show the names."""
    rr = require_rerun()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(application_id)
    rec.save(str(path))
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    if len(class_names):
        colours = palette if palette is not None else np.zeros((len(class_names), 3), np.uint8)
        rec.log("/", rr.AnnotationContext([rr.AnnotationInfo(id=i, label=name, color=tuple(int(c) for c in colours[i]))
                                          for i, name in enumerate(class_names)]), static=True)
    return rec


def log_camera(rec, entity: str, pose: np.ndarray, intrinsics: np.ndarray, width: int, height: int) -> None:
    """Camera at ``pose`` (4, 4) world-from-camera, OpenCV axes, pinhole ``intrinsics`` (3, 3)."""
    rr = require_rerun()
    rec.log(entity, rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]),
            rr.Pinhole(image_from_camera=intrinsics, width=width, height=height, camera_xyz=rr.ViewCoordinates.RDF))


def jpeg_image(rgb: np.ndarray, quality: int = 90):
    """An ``rr.EncodedImage`` of rgb (H, W, 3) uint8 as JPEG (OpenCV's encoder: half the time of
    ``rr.Image(...).compress``)."""
    import cv2

    rr = require_rerun()
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(rgb[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError(f"could not JPEG-encode a {rgb.shape} image")
    return rr.EncodedImage(contents=buf.tobytes(), media_type="image/jpeg")


def confidence_colours(confidence: np.ndarray, num_classes: int) -> np.ndarray:
    """(N, 3) uint8 viridis colours of arg-max probabilities in [1/K, 1] (1/K: darkest)."""
    from matplotlib import colormaps

    low = 1.0 / max(num_classes, 1)
    t = np.clip((np.asarray(confidence, np.float64) - low) / max(1.0 - low, 1e-9), 0.0, 1.0)
    return np.round(colormaps["viridis"](t)[:, :3] * 255).astype(np.uint8)


def log_voxels(rec, entity: str, coords: np.ndarray, probs: np.ndarray, voxel_size_m: float,
               palette: np.ndarray, static: bool = False) -> None:
    """A voxel map's surface voxels: coords (N, 3) float world metres (centres), probs (N, K)
    fused probabilities; ``<entity>/class`` and ``<entity>/confidence`` (module docstring).
    ``static``: one map for the whole recording (no time)."""
    rr = require_rerun()
    coords = np.asarray(coords, np.float32)
    cls = probs.argmax(axis=1) if len(probs) else np.zeros(0, np.int64)
    conf = probs[np.arange(len(cls)), cls].astype(np.float32) if len(probs) else np.zeros(0, np.float32)
    radius = VOXEL_RADIUS_FRACTION * voxel_size_m
    rec.log(f"{entity}/class", rr.Points3D(coords, class_ids=cls.astype(np.uint16), radii=radius), static=static)
    rec.log(f"{entity}/confidence", rr.Points3D(coords, colors=confidence_colours(conf, probs.shape[1]), radii=radius),
            rr.AnyValues(confidence=conf), static=static)


def log_mask_points(rec, entity: str, coords: np.ndarray, colours: np.ndarray, voxel_size_m: float,
                    values: dict[str, np.ndarray] | None = None, static: bool = False) -> None:
    """Points with explicit colours (N, 3) uint8 and optional per-point value columns."""
    rr = require_rerun()
    extra = [rr.AnyValues(**values)] if values else []
    rec.log(entity, rr.Points3D(np.asarray(coords, np.float32), colors=colours,
                                radii=VOXEL_RADIUS_FRACTION * voxel_size_m), *extra, static=static)


def check_recording(path: str | Path) -> None:
    """ValueError (one line) unless ``path`` is a Rerun recording the viewer can open: a
    non-empty file that starts with Rerun's stream header (``RRD_MAGIC`` and its version)
    and that Rerun's reader opens. A recording cut short by a killed run still opens (its
    complete messages are shown); only the start of the file is read, never the whole stream."""
    path = Path(path)
    size = path.stat().st_size
    if size == 0:
        raise ValueError(f"{path} is empty (0 bytes), not a Rerun recording; record it again")
    with path.open("rb") as f:
        head = f.read(len(RRD_MAGIC) + 1)   # the FourCC: the magic and its format digit
    if not head.startswith(RRD_MAGIC):
        raise ValueError(f"{path} is not a Rerun recording: an .rrd file starts with {RRD_MAGIC.decode()!r} "
                         f"(e.g. RRF2), this one with {head!r}")
    require_rerun("reading a recording")
    import warnings

    from rerun.chunk import RrdReader

    try:
        with warnings.catch_warnings():   # a recording without its footer (cut short) is read by a scan
            warnings.simplefilter("ignore")
            RrdReader(str(path))
    except (RuntimeError, ValueError, OSError) as exc:
        detail = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ValueError(f"{path} is not a readable Rerun recording ({size} bytes): {detail}") from None


def read_columns(path: str | Path) -> dict[str, Any]:
    """Every entity of the ``.rrd`` at ``path`` (its first recording) -> a pyarrow Table of its
    rows (one per log call; the timelines and the components as columns), read with Rerun's
    own chunk reader."""
    import pyarrow as pa

    require_rerun("reading a recording")
    from rerun.chunk import RrdReader

    batches: dict[str, list] = {}
    for chunk in RrdReader(str(path)).stream().to_chunks():
        batches.setdefault(str(chunk.entity_path), []).append(chunk.to_record_batch())
    out = {}
    for entity, parts in batches.items():
        tables = [pa.Table.from_batches([b]) for b in parts]
        out[entity] = pa.concat_tables(tables, promote_options="permissive")
    return out
