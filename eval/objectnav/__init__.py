"""ObjectNav experiments: ``run`` (``calnav objectnav``: episodes, resume, multirun), ``report``
(tables and plots), ``compare``, ``tune``, ``study`` (``calnav study``: tune on one split,
evaluate on another, with a manifest; its config schema in ``study_config``), ``start_pose``,
``view_episode`` and ``demo``."""
