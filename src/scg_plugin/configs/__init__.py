"""SCGaussian's named config variants (the paper's ablation and matcher rows), shipped as package data."""
