"""Configuration of ``calnav map`` (``configs/map_sequence.yaml``). The recorded-sequence list of
``calnav calibrate-map --sequences`` is ``eval.calibration.config.SequenceSetConfig``."""
from __future__ import annotations

from dataclasses import dataclass, field

from calnav.agent.segmenters.base import SegmenterConfig
from calnav.eval.config import RunConfig
from calnav.mapping.config import MappingConfig
from calnav.mapping.sequences import SequenceConfig


@dataclass
class MapSequenceConfig:
    """``configs/map_sequence.yaml``."""

    mapping: MappingConfig = field(default_factory=MappingConfig)
    sequence: SequenceConfig = field(default_factory=SequenceConfig)
    segmenter: SegmenterConfig = field(default_factory=SegmenterConfig)
    run: RunConfig = field(default_factory=RunConfig)
