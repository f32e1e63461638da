"""Configuration of ``calnav map`` (``configs/map_sequence.yaml``) and of the recorded-sequence
list of ``calnav calibrate-map --sequences``."""
from __future__ import annotations

from dataclasses import dataclass, field

from agent.segmenters.base import SegmenterConfig
from eval.config import RunConfig
from mapping.config import MappingConfig
from mapping.sequences import LayoutName, SequenceConfig


@dataclass
class SequenceSetConfig:
    """Recorded sequences replacing calnav's houses in ``calnav calibrate-map``."""

    list: str = ""                   # list file, one "<role> <dir> [layout]" per line (role: calib_train | calib_val | test); "" = calnav houses
    layout: LayoutName = "scannet"   # layout of listed sequences that name none: scannet | 7scenes


@dataclass
class MapSequenceConfig:
    """``configs/map_sequence.yaml``."""

    mapping: MappingConfig = field(default_factory=MappingConfig)
    sequence: SequenceConfig = field(default_factory=SequenceConfig)
    segmenter: SegmenterConfig = field(default_factory=SegmenterConfig)
    run: RunConfig = field(default_factory=RunConfig)
