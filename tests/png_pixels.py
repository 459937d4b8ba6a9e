"""Test helper: a PNG's pixels as Blender's own reader decodes them (no imaging library in the venv)."""

import numpy as np


def png_pixels(path):
    """(H, W, 3) floats in 0..255, top row first."""
    import bpy  # bpy: Blender starts on first import

    img = bpy.data.images.load(str(path))
    try:
        w, h = img.size
        px = np.empty(w * h * 4, dtype=np.float32)
        img.pixels.foreach_get(px)
    finally:
        bpy.data.images.remove(img)
    return np.round(px.reshape(h, w, 4)[::-1, :, :3] * 255.0)
