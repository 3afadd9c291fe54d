"""splat: a modular Gaussian-splatting framework (the public face for plugins is
:mod:`splat_framework.plugin`)."""
