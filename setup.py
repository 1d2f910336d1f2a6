"""Package discovery that pyproject.toml alone cannot express: every ``hilbench.*`` package is found,
and ``profiles/`` at the top of the repository ships as ``hilbench.profiles`` (see ``package-dir``)."""

from setuptools import find_packages, setup

setup(packages=[*find_packages(include=["hilbench", "hilbench.*"]), "hilbench.profiles"])
