"""Time enabling the installed extension in a fresh Blender, as at start-up (run by a bpy-wheel Python).

    python matrix_enable.py RESULT.json

The extension must already be installed in the user folders the environment points at. Writes how long
``addon_enable`` took (wall clock, and this process's CPU time, which a busy machine disturbs less), which
heavy modules it loaded (none expected: scipy and OpenCV load when a feature first needs them), and, as the
naive baseline, how long importing them up front would add.
"""

import json
import sys
import time

import bpy

ADDON = "bl_ext.user_default.facecap"

start, cpu = time.perf_counter(), time.process_time()
result = bpy.ops.preferences.addon_enable(module=ADDON)
enable, enable_cpu = time.perf_counter() - start, time.process_time() - cpu
heavy = sorted(m for m in ("scipy", "cv2") if m in sys.modules)
start, cpu = time.perf_counter(), time.process_time()
import cv2  # noqa: E402,F401  the cost a module-level import in the add-on would add to every start-up
import scipy.interpolate  # noqa: E402,F401
import scipy.linalg  # noqa: E402,F401
import scipy.ndimage  # noqa: E402,F401
import scipy.signal  # noqa: E402,F401

eager, eager_cpu = time.perf_counter() - start, time.process_time() - cpu
with open(sys.argv[-1], "w", encoding="utf-8") as fh:
    json.dump({"result": sorted(result), "enabled": ADDON in bpy.context.preferences.addons, "enable_seconds": enable,
               "enable_cpu_seconds": enable_cpu, "heavy_after_enable": heavy, "eager_import_seconds": eager,
               "eager_import_cpu_seconds": eager_cpu}, fh)
