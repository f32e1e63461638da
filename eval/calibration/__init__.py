"""The map-calibration study (``calnav calibrate-map``, ``calnav fit-glfs``; its config sections
``study`` and ``sequences`` live in ``eval.sections``, beside the root config's), ``record``
(calibration scans of houses, or recorded sequences, into observation caches), ``study``
(fitting and scoring every strategy x calibration), ``report`` and ``plots``."""
