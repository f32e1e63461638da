"""``python -m calnav``: the ``calnav`` command."""
import sys

from calnav.eval.cli import main

sys.exit(main())
