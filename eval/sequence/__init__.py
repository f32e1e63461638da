"""Recorded RGB-D sequences: ``calnav map`` (map and score a recording), ``calnav export-sequence``
(calnav's own frames in ScanNet layout) and the recorded-sequence frame source of
``calnav calibrate-map --sequences``."""
