"""The mapping package's parts chosen by name, one ``Registry`` each (``common.registry``):

| registry | chosen by | parts |
|---|---|---|
| ``FUSIONS`` | ``mapping.fusion`` | ``rbu``, ``averaging``, ``histogram``, ``geometric_mean``, ``glfs`` (``mapping.fusion.Strategy``) |
| ``WEIGHTINGS`` | ``mapping.weighting`` (or ``auto``) | ``none``, ``lut``, ``distance``, ``incidence``, ``sweet_spot`` (``mapping.weighting``) |
| ``LAYOUTS`` | ``calnav map --layout``, ``sequences.layout``, a sequence list's third column | ``scannet``, ``7scenes`` (``mapping.sequences.readers``), ``rosbag`` (``mapping.sequences.rosbag``) |

Every part is a lazy ``"module:attribute"`` reference into the module that implements it
(``mapping.fusion`` and ``mapping.weighting`` import torch, ``mapping.sequences`` OpenCV), so
this module imports nothing heavy: ``MappingConfig`` checks a name and the CLI lists the
layouts before either loads. A new part is implemented in its module and registered here.

    FUSIONS.check("glfs")              # the name, or ValueError naming the valid choices
    strategy = FUSIONS.get("glfs")     # mapping.fusion.GLFS (imports torch on first use)
"""
from __future__ import annotations

from typing import Any, Callable

from calnav.common.registry import Registry

# name -> ``mapping.fusion.Strategy`` (its accumulators and read-out: mapping.fusion's table)
FUSIONS: Registry[Any] = Registry("fusion strategy", key="mapping.fusion")
FUSIONS.add("rbu", "calnav.mapping.fusion:RBU", "recursive Bayesian update: softmax of the summed log-probabilities")
FUSIONS.add("averaging", "calnav.mapping.fusion:AVERAGING", "weighted mean of the probabilities")
FUSIONS.add("histogram", "calnav.mapping.fusion:HISTOGRAM", "weighted arg-max votes")
FUSIONS.add("geometric_mean", "calnav.mapping.fusion:GEOMETRIC_MEAN", "softmax of the mean log-probability")
FUSIONS.add("glfs", "calnav.mapping.fusion:GLFS", "gated log-linear blend of rbu and averaging (learned G, eps, tau)")

# name -> weight function ``(pred, distance_m, angle_deg, WeightingParams) -> w`` (mapping.weighting)
WEIGHTINGS: Registry[Callable[..., Any]] = Registry("sample weighting", key="mapping.weighting")
WEIGHTINGS.add("none", "calnav.mapping.weighting:none_weights", "w = 1")
WEIGHTINGS.add("lut", "calnav.mapping.weighting:lut_weights", "GLFS look-up table M[class, distance bin, angle bin]")
WEIGHTINGS.add("distance", "calnav.mapping.weighting:distance_weights", "inverse-square falloff beyond distance_ref_m")
WEIGHTINGS.add("incidence", "calnav.mapping.weighting:incidence_weights", "cosine of the incidence angle")
WEIGHTINGS.add("sweet_spot", "calnav.mapping.weighting:sweet_spot_weights",
               "quadratic around the segmenter's best distance sweet_spot_m")
# ``mapping.weighting`` may also name no part: "auto" is resolved by the fusion strategy
# (``mapping.weighting.resolve``: the GLFS table for glfs, none for every other strategy)
AUTO_WEIGHTING = "auto"

# name -> opener ``(root: Path) -> (frame ids, paths(id) -> dict, K colour (3, 3), K depth (3, 3))``
# (mapping.sequences.readers; ``Sequence`` opens a recording with it)
LAYOUTS: Registry[Callable[..., tuple]] = Registry("sequence layout")
LAYOUTS.add("scannet", "calnav.mapping.sequences.readers:open_scannet",
            "ScanNet SensReader export: color/N.jpg, depth/N.png, pose/N.txt, intrinsic/")
LAYOUTS.add("7scenes", "calnav.mapping.sequences.readers:open_7scenes",
            "7-Scenes / 3DMatch: frame-NNNNNN.{color,depth,pose}, camera-intrinsics.txt")
# a ``Sequence`` subclass reads its recording itself (``Sequence(bag, "rosbag")`` is one)
LAYOUTS.add("rosbag", "calnav.mapping.sequences.rosbag:RosbagSequence",
            "ROS 1 .bag / ROS 2 bag (sqlite3, mcap): image, CameraInfo and TF or pose topics (sequence.rosbag)")


def weighting_choices() -> tuple[str, ...]:
    """The valid ``mapping.weighting`` values: ``auto`` and every registered weighting."""
    return (AUTO_WEIGHTING, *WEIGHTINGS.names())


def check_weighting(name: object) -> str:
    """``name`` if it is ``auto`` or a registered weighting; else a one-line ValueError naming
    the valid choices (``auto`` included)."""
    if name != AUTO_WEIGHTING and (not isinstance(name, str) or name not in WEIGHTINGS):
        raise ValueError(f"unknown {WEIGHTINGS.kind} {name!r} for {WEIGHTINGS.key}; "
                         f"valid choices: {', '.join(weighting_choices())}")
    return name
