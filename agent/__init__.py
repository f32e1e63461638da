"""The ObjectNav agent: segmenters (``agent.segmenters``) and the PEANUT-like semantic-map
agent (``agent.policy.PeanutAgent``, ``calnav objectnav --agent peanut``), composed of one part
per stage, one file per stage:

| stage | file | what it does |
|---|---|---|
| contract | ``contract.py`` | the ``Observation`` (Habitat's keys) the parts read, the ``Privileged`` part only a part declaring it gets, the ``Agent`` protocol |
| registries | ``registry.py`` | ``MAP_BUILDERS`` (``agent.map_type``), ``GOAL_SELECTORS`` (``agent.exploration``), ``AGENTS`` (``run.agent``: peanut, oracle) |
| config | ``config.py`` | ``AgentConfig`` (YAML section ``agent``), every default with its unit |
| setup | ``setup.py`` | ``AgentSetup``: what an agent is built from (its sections, the task's ``SensorSetup``, the device), and ``build_agent`` |
| perceive | ``perception.py`` | subsample to 160x120 and segment: ``mapping.frame.SegmentedFrame`` (depth, k, logits, rgb) |
| map | ``semantic_map.py`` | ``MapChannels``, ``MapState`` (2D map + the episode's 3D voxel map) and the map builders (``FusedMapBuilder``, ``NdfMapBuilder``): incremental ground projection |
| grid geometry | ``projection.py`` | back-projection, cell indices, free rays, discs, dilation |
| detect | ``goal_detection.py`` | accept (threshold + largest connected component with a minimum area), verify / reject, defer |
| select | ``goal_selection.py`` | the long-term goal: ``FrontierSelector`` (``exploration.py``: frontiers by geodesic distance and size, + optional co-occurrence prior), ``PredictionSelector`` (``prediction.py``: PEANUT's target prediction) |
| plan | ``planner.py`` | ``Planner``: geodesic field to the goal region, short-term goal on a ring, TURN / FORWARD |
| act | ``approach.py`` | where to STOP at a goal (its view region, facing it) and where to plan to |
| collisions | ``collision.py`` | blocked-move detection, obstacle marks ahead, the escape (every heading in turn until one moves; started by blocks or by the watchdog) |
| watchdog | ``watchdog.py`` | no progress, going round in circles |
| policy | ``policy.py`` | ``PeanutAgent``: reset / act composing the stages, forced STOP at the step limit |
| library | ``navigator.py``, ``navigator_map.py`` | ``Navigator``: the agent as a library and as every command runs it (goal by name, pose -> gps / compass, decisions and maps in metres; ``EpisodeAgent``: it in the episode loop); ``AgentMap``: its map, read and saved |
| oracle | ``oracle.py`` | ``OracleAgent``: the shortest-path follower through the env's privileged handle |
| visualisation | ``visualize.py`` | per-step panel (RGB, segmentation, top-down map) and episode video |
"""
