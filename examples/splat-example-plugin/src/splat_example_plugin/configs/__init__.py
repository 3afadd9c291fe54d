"""The plugin's config variants (TOML files), found through its ``splat_framework.configs`` entry."""
