"""The ObjectNav agent: segmenters (``agent.segmenters``) and the PEANUT-like semantic-map
agent (``agent.policy.PeanutAgent``, ``calnav objectnav --agent peanut``), one file per stage:

| stage | file | what it does |
|---|---|---|
| config | ``config.py`` | ``AgentConfig`` (YAML section ``agent``), every default with its unit |
| perception | ``perception.py`` | subsample to 160x120 and segment: ``mapping.frame.SegmentedFrame`` (depth, k, logits, rgb) |
| maps | ``semantic_map.py`` | ``MapChannels``, ``MapState`` (2D map + the episode's 3D voxel map) and ``SemanticMapModule``: fuse into the voxel map, incremental ground projection |
| grid geometry | ``projection.py`` | back-projection, cell indices, free rays, discs, dilation |
| goal detection | ``goal_detection.py`` | threshold + largest connected component with a minimum area |
| exploration | ``exploration.py`` | frontiers, scored by geodesic distance and size (+ optional co-occurrence prior) |
| local planning | ``planner.py`` | ``Planner``: geodesic field to the goal region, short-term goal on a ring, TURN / FORWARD |
| collisions | ``collision.py`` | blocked-move detection, obstacle marks ahead, the escape (every heading in turn until one moves; started by blocks or by the policy's no-progress watchdog) |
| policy | ``policy.py`` | ``PeanutAgent``: reset / act, the decision logic, forced STOP at the step limit |
| visualisation | ``visualize.py`` | per-step panel (RGB, segmentation, top-down map) and episode video |
"""
