"""The package list of the wheel; everything else is in pyproject.toml.

The repository's top-level `models/` and `diagrams/` (the source of truth, see the layout in
README.md) ship inside the package as `nbvs_drake.models` and `nbvs_drake.diagrams`
(pyproject.toml's package-dir maps them there and its package-data takes every file in them).
pyproject.toml alone cannot both discover the package's subpackages and add these two mapped
ones, hence this file: the subpackages are found as `packages.find` found them (namespace
packages included), so a new subpackage ships without editing anything."""

from setuptools import find_namespace_packages, setup

setup(packages=find_namespace_packages(include=["nbvs_drake", "nbvs_drake.*"], exclude=["*.__pycache__"])
      + ["nbvs_drake.models", "nbvs_drake.diagrams"])
