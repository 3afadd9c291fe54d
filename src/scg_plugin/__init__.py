"""SCGaussian (Peng et al., NeurIPS 2024) as a plugin of splat, importing the framework only
through :mod:`splat_framework.plugin`. Its parts, in one table: :data:`ENTRY_POINTS` (the
project's pyproject.toml declares the same entry points; a test checks they agree)."""

ENTRY_POINTS = {
    "splat_framework.methods": {"scgaussian": "scg_plugin.method:spec_scgaussian"},
}
"""Every part of this plugin, by entry-point group (its paper rows are config variants in the
project's top-level ``configs/``, package ``splat_configs``)."""
