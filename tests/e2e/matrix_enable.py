"""Time enabling the installed extension in a fresh Blender, as at start-up (run by a bpy-wheel Python).

    python matrix_enable.py RESULT.json

The extension must already be installed in the user folders the environment points at. Prints how long
``addon_enable`` took, which heavy modules it loaded (none expected: scipy and OpenCV load when a
feature first needs them), and, as the naive baseline, how long importing them up front would add.
"""

import json
import sys
import time

import bpy

ADDON = "bl_ext.user_default.facecap"

start = time.perf_counter()
result = bpy.ops.preferences.addon_enable(module=ADDON)
enable = time.perf_counter() - start
heavy = sorted(m for m in ("scipy", "cv2") if m in sys.modules)
start = time.perf_counter()
import cv2  # noqa: E402,F401  the cost a module-level import in the add-on would add to every start-up
import scipy.interpolate  # noqa: E402,F401
import scipy.linalg  # noqa: E402,F401
import scipy.ndimage  # noqa: E402,F401
import scipy.signal  # noqa: E402,F401

eager = time.perf_counter() - start
with open(sys.argv[-1], "w", encoding="utf-8") as fh:
    json.dump({"result": sorted(result), "enabled": ADDON in bpy.context.preferences.addons, "enable_seconds": enable,
               "heavy_after_enable": heavy, "eager_import_seconds": eager}, fh)
