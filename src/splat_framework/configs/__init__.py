"""Named config variants of the built-in methods, shipped as package data."""
