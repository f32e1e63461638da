"""Experiments and the ``calnav`` command line.

At the top: ``cli.py`` (argument parsing and dispatch only), ``config.py`` (the typed YAML
loader with dotted overrides, shared by every experiment) and ``stats.py`` (means, SEMs,
paired differences). One package per experiment:

| package | commands | what is in it |
|---|---|---|
| ``eval.objectnav`` | ``objectnav``, ``tune``, ``compare``, ``view-episode``, ``demo``, ``make study`` | episode runs, agent registry, reports and tables, tuning, the study script |
| ``eval.calibration`` | ``calibrate-map``, ``fit-glfs`` | the map-calibration study: config, recording, fitting, report, plots |
| ``eval.bench`` | ``bench`` | one module per figure family, chosen by name in ``eval.bench.run.SECTIONS`` |
| ``eval.segmenter`` | ``train-segmenter``, ``eval-segmenter`` | frame data, training, evaluation |

Subcommands never import ``eval.cli``.
"""
