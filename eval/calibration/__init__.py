"""The map-calibration study (``calnav calibrate-map``, ``calnav fit-glfs``): ``config``
(``CalibrateMapConfig``), ``record`` (calibration scans of houses into observation caches),
``study`` (fitting and scoring every strategy x calibration), ``report`` and ``plots``."""
