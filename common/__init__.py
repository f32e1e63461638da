"""Shared mechanisms with no project imports: everything may import ``common``; it imports no
project package (``agent``, ``envs``, ``mapping``, ``eval``).

- ``common.atomic``: atomic file writes (unique temporary file, fsync, ``os.replace``), whole
  contents or through a temporary path for writers such as ``np.savez`` / ``torch.save``.
- ``common.npz``: save / load a versioned ``.npz`` (arrays + a JSON metadata record carrying
  ``format_version``), with clear errors naming the file.
- ``common.weights``: versioned torch weight dicts (``torch.load(weights_only=True)`` + a format
  number), with errors naming the file and the command that makes it.
- ``common.threads``: the thread budget of a worker process (OpenMP, BLAS, torch, the renderer).
- ``common.rerun_io``: Rerun recordings (the ``[viz]`` extra): cameras, voxel maps by class and
  confidence, reading a ``.rrd`` back.
- ``common.prefetch``: an iterator's items produced a bounded number ahead by a background
  thread, exceptions re-raised in the consumer.
"""
