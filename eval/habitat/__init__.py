"""``calnav habitat-benchmark``: agents run through habitat-lab's ``habitat.Benchmark`` on calnav
houses (``envs.habitat_sim_backend``), with ``calnav objectnav``'s results files."""
