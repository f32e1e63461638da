"""Experiments and the ``calnav`` command line.

At the top: ``cli.py`` (the command registry ``COMMANDS`` and dispatch: it loads each
command's configs once), ``parser.py`` (every command's arguments) and ``preflight.py`` (the file checks ``cli`` runs on those
configs before the command; it sits above the experiments). Shared by every experiment: ``config.py`` (the typed YAML loader with dotted
overrides), ``results_dir.py`` (results directories, records), ``backends.py`` (process / Ray
execution) and ``stats.py`` (means, SEMs, paired differences). One package per experiment:

| package | commands | what is in it |
|---|---|---|
| ``eval.objectnav`` | ``objectnav``, ``tune``, ``compare``, ``view-episode``, ``start-pose``, ``demo``, ``make study`` | episode runs, agent registry, reports and tables, tuning, the study script |
| ``eval.calibration`` | ``calibrate-map``, ``fit-glfs`` | the map-calibration study: config, recording (house scans and recorded sequences), fitting, report, plots |
| ``eval.sequence`` | ``map``, ``export-sequence`` | recorded RGB-D sequences: mapping and scoring one, calnav frames in ScanNet layout |
| ``eval.habitat`` | ``habitat-benchmark`` | the calnav agent through habitat-lab's benchmark |
| ``eval.scanning`` | ``scan-houses`` | scanned (reconstructed) houses |
| ``eval.bench`` | ``bench`` | one module per figure family, chosen by name in ``eval.bench.run.SECTIONS`` |
| ``eval.segmenter`` | ``train-segmenter``, ``eval-segmenter`` | frame data, training, evaluation |

The shared modules import no experiment; an experiment imports the shared modules and only the
experiments ``tests/test_layering.py`` (``EVAL_ALLOWED``) declares for it (``bench`` ->
``objectnav``, ``sequence``; ``habitat`` -> ``objectnav``; ``sequence`` -> ``calibration``),
with no cycle. Only ``eval.cli`` imports ``eval.preflight``; nothing imports ``eval.cli``.
"""
