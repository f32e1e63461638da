"""Packages of the wheel: each top-level folder of the repository (``agent/``, ``envs/``, ...) is
installed under ``calnav`` (``calnav.agent``, ...), every subpackage found automatically (data
folders such as ``agent/weights`` too, as namespace packages holding package data: see
pyproject.toml). The rest of the metadata is in pyproject.toml."""
from setuptools import find_namespace_packages, setup

FOLDERS = ("common", "envs", "mapping", "agent", "eval", "configs")

setup(
    packages=["calnav"] + [f"calnav.{p}" for p in find_namespace_packages(
        include=[f"{f}{s}" for f in FOLDERS for s in ("", ".*")], exclude=["*__pycache__*"])],
    package_dir={"calnav": "calnav", **{f"calnav.{f}": f for f in FOLDERS}},
)
