"""The map-calibration study (``calnav calibrate-map``, ``calnav fit-glfs``): ``config``
(``CalibrateMapConfig``, with the recorded-sequence list ``SequenceSetConfig``), ``record``
(calibration scans of houses, or recorded sequences, into observation caches), ``study``
(fitting and scoring every strategy x calibration), ``report`` and ``plots``."""
