"""splat: a modular Gaussian-splatting framework (the public API for plugins is
:mod:`splat_framework.plugin`)."""
