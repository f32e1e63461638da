"""Recorded RGB-D sequences: ``calnav map`` (map and score a recording) and ``calnav export-sequence``
(calnav's own frames in ScanNet layout). The recorded-sequence frame source of
``calnav calibrate-map --sequences`` belongs to the calibration study
(``eval.calibration.record.RecordedScan``)."""
