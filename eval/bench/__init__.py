"""``calnav bench``: ``run`` (sections by name, table, JSON), ``context`` (the shared scene,
trajectory and frames) and one module per figure family: ``env``, ``fusion``, ``segmenter``,
``agent``."""
