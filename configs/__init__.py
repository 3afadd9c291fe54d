"""The project's named config variants: one TOML per row of the paper and per variant of a built-in method.

This folder is installed as the package ``splat_configs`` (``setup.py`` maps it) and
listed in the ``splat_framework.configs`` entry-point group, the group through which
plugins ship their own variants; ``splat_framework.registry`` finds it with
``importlib.resources`` from a checkout, an editable install or a wheel alike.
"""
