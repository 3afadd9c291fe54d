"""Packaging beyond pyproject.toml: the top-level ``configs/`` folder ships as the package ``splat_configs``.

(pyproject.toml's package discovery cannot map a folder outside ``src/`` under another
name; everything else lives in pyproject.toml.)
"""

from setuptools import find_packages, setup

setup(
    packages=[*find_packages("src"), "splat_framework.render.native", "splat_configs"],  # native: the C++ sources
    package_dir={"": "src", "splat_configs": "configs"},
)
