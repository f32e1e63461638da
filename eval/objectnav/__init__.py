"""ObjectNav experiments: ``run`` (``calnav objectnav``: episodes, resume, multirun), ``agents``
(the agent registry), ``report`` (tables and plots), ``compare``, ``tune``, ``view_episode``,
``demo`` and ``study.sh`` (``make study``)."""
