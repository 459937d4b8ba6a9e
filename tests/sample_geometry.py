"""The sample character's numpy-only generator (``sample_blends/character_geometry.py``), for tests
that need its mesh, vertex groups or shape keys without Blender (sample_blends is not a package)."""

import importlib
import sys
from pathlib import Path

SAMPLE_DIR = Path(__file__).resolve().parents[1] / "sample_blends"


def geometry_module():
    """The ``character_geometry`` module of ``sample_blends``."""
    sys.path.insert(0, str(SAMPLE_DIR))
    try:
        return importlib.import_module("character_geometry")
    finally:
        sys.path.remove(str(SAMPLE_DIR))
