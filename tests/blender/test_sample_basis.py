"""The Blender-free tests use character_basis.npz; it must be what the add-on reads from the .blend."""

import json
from pathlib import Path

import bpy
import numpy as np

from facecap.facecap_addon.scene.scene_data import basis_from_object
from facecap.solvers import Basis

SAMPLES = Path(__file__).resolve().parents[2] / "sample_blends"


def test_exported_basis_matches_the_blend():
    bpy.ops.wm.open_mainfile(filepath=str(SAMPLES / "character.blend"))
    layout = json.loads((SAMPLES / "marker_layout.json").read_text())
    names = [m["name"] for m in layout["markers"]]
    live = basis_from_object(bpy.data.objects[layout["object"]], names)
    saved = Basis.load_npz(SAMPLES / "character_basis.npz")
    assert live.shape_names == saved.shape_names and live.marker_names == saved.marker_names
    np.testing.assert_allclose(live.neutral, saved.neutral, atol=1e-9)
    np.testing.assert_allclose(live.deltas, saved.deltas, atol=1e-9)
    np.testing.assert_array_equal(live.upper, 1.0)
