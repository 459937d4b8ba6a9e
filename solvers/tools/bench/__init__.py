"""Blender-free benchmarks (``python -m facecap bench``) and the plain reference methods they compare with."""
