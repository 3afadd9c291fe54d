"""Evaluation: held-out views (held_out), pictures (PNG, colour maps), metrics, ST-LPIPS, test-time pose refinement, figures."""
