"""calnav's YAML configs, shipped as package data (``calnav.configs``): a ``--config`` path that
does not exist from the working directory is looked up here by file name."""
