"""calnav: an ObjectNav agent on a calibrated semantic 3D map.

The project's packages sit beside this folder in the repository (``agent/``, ``common/``,
``envs/``, ``eval/``, ``mapping/``, ``configs/``) and are installed under this one name
(``calnav.agent``, ``calnav.mapping``, ...): generic names such as ``eval`` or ``mapping`` never
shadow, or are shadowed by, another distribution's top-level package.
"""
from pathlib import Path

__version__ = "0.1.0"

_HERE = Path(__file__).resolve().parent
if not (_HERE / "eval").is_dir() and (_HERE.parent / "eval" / "cli.py").is_file():
    # a source checkout (editable install or PYTHONPATH=<repo>): calnav.agent is <repo>/agent
    __path__.append(str(_HERE.parent))  # noqa: F821 (a package's __path__)
