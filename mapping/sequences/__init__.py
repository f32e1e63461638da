"""Recorded RGB-D sequences as a stream of posed frames (``SequenceFrame``), one reader per layout
(``LAYOUTS``, i.e. ``mapping.registry.LAYOUTS``):

- ``scannet`` (ScanNet's SensReader export): ``color/N.jpg`` (1296x968), ``depth/N.png``
  (uint16, 640x480), ``pose/N.txt`` (4x4 camera-to-world), ``intrinsic/intrinsic_color.txt`` and
  ``intrinsic/intrinsic_depth.txt`` (4x4; the top-left 3x3 is K). Optional per-frame labels:
  ``semantic/N.png`` (uint16 class id + 1, 0 = void; written by ``calnav export-sequence``) or
  ScanNet's ``label-filt/N.png`` (uint16 raw ScanNet ids, read when ``frame_label_map`` names the
  id -> name table, e.g. ``scannetv2-labels.combined.tsv``, and the class list is known:
  ``Sequence.use_class_names``), at the colour or the depth resolution.
  Ground truth: ``<scene>_vh_clean_2.labels.ply`` (per-vertex ``label``, NYU40 ids on ScanNet).
- ``7scenes`` (7-Scenes / 3DMatch): ``frame-NNNNNN.color.{png,jpg}``, ``frame-NNNNNN.depth.png``
  (uint16 millimetres, 0 = missing, 65535 = invalid), ``frame-NNNNNN.pose.txt`` and
  ``camera-intrinsics.txt`` (3x3, in the sequence folder or its parent; colour and depth share it,
  as in 3DMatch -- 7-Scenes' own colour is not registered to its depth: colours and colour-based
  logits are then off by the sensors' baseline, a few pixels).
- ``rosbag`` (a ROS 1 ``.bag`` or a ROS 2 bag, read with ``rosbags``): colour, registered depth
  and CameraInfo topics, poses from TF or a pose topic, frames paired by stamp
  (``mapping.sequences.rosbag``; keys ``sequence.rosbag``, ``rosbag_config``).

Every reader streams: ``Sequence.frames()`` decodes one frame at a time, so memory does not grow
with the recording. Frames whose pose is not finite (ScanNet writes rows of ``-inf`` where
tracking failed) are skipped and listed with their reason in ``Sequence.skips``
(``mapping.sequences.skips``: one rule for every layout, bags' shared stamps and repeated
messages too); a clearly non-rigid pose
raises ValueError naming the frame; nearly rigid ones are re-orthonormalised
(``frame_geometry.check_pose``). Depth: raw / ``depth_scale`` metres, raw 0 and
``invalid_depth_raw`` set to 0 (invalid), depth beyond ``depth_trunc_m`` set to 0.

Colour and depth may differ in resolution (ScanNet): ``Registration`` resamples colour-camera
images (rgb, labels, logits) onto the depth camera through the two intrinsics -- a depth pixel
(u, v) reads the colour image at K_c K_d^-1 (u, v, 1) (the cameras share their optical centre,
as in ScanNet's registered export). rgb is resampled bilinearly with ``cv2.remap``; class
labels and logits by nearest neighbour (an index gather: any K, no blending of label ids);
pixels falling outside the colour image get void / all-zero (uniform) logits. ``cv2.resize``
is not used: it assumes the principal points scale with the image size, which ScanNet's do not.
"""

from calnav.mapping.sequences.labels import LogitsDir, label_map_source, read_class_list, vertex_ground_truth
from calnav.mapping.registry import LAYOUTS
from calnav.mapping.sequences.readers import (SEMANTIC_OFFSET, VOID, Sequence, SequenceConfig, SequenceFrame,
                                       depth_from_raw, read_7scenes, read_intrinsics, read_scannet)
from calnav.mapping.sequences.registration import Registration

__all__ = ["LAYOUTS", "SEMANTIC_OFFSET", "VOID", "LogitsDir", "Registration", "Sequence", "SequenceConfig",
           "SequenceFrame", "depth_from_raw", "label_map_source", "read_7scenes", "read_class_list", "read_intrinsics",
           "read_scannet", "vertex_ground_truth"]
