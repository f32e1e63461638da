"""Segmenter experiments: ``data`` (rendered frame sets, cached), ``train``
(``calnav train-segmenter``) and ``evaluate`` (``calnav eval-segmenter``)."""
