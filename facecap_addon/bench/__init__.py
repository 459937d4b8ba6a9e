"""Blender-side benchmarks and the test rigs they use (``python -m facecap bench``, ``rig-bench``)."""
