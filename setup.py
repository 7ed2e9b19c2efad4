"""Package layout that pyproject.toml cannot say: the streaming nodes live in the repository's `nodes/` folder
and install as `sonar_realism_nodes` (never as a top-level `nodes`). Everything else is in pyproject.toml."""

from setuptools import find_packages, setup

setup(packages=[*find_packages(include=["sonar_realism", "sonar_realism.*"]), "sonar_realism_nodes"],
      package_dir={"sonar_realism_nodes": "nodes"})
