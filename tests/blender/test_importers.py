"""File > Import operators for every marker format, and the scene they build."""

import bpy
import numpy as np
import pytest

from facecap.facecap_addon.scene import anim, take
from facecap.operators import importers
from facecap.solvers import MarkerSet
from facecap.solvers.io import write_markers


def make_take():
    rng = np.random.default_rng(3)
    pos = rng.normal(size=(30, 4, 3)) * 10
    pos[5:8, 2] = np.nan
    return MarkerSet(("browL", "browR", "lipT", "chin"), np.arange(11, 41), pos, fps=50, units="mm",
                     segments={"posed_neutral": [(12.0, 20.0)], "posed_happy": [(25.0, 35.0)]})


@pytest.mark.parametrize("ext, op", [("c3d", "import_c3d"), ("trc", "import_trc"), ("csv", "import_csv"),
                                     ("json", "import_json")])
def test_import_each_format_builds_keyed_empties(empty_scene, tmp_path, ext, op):
    m = make_take()
    path = tmp_path / f"take07.{ext}"
    write_markers(path, m)
    kwargs = {"filepath": str(path)}
    if ext == "csv":
        kwargs.update(units="mm", fps=50.0)
    assert getattr(bpy.ops.facecap, op)(**kwargs) == {"FINISHED"}
    scene = bpy.context.scene
    coll = bpy.data.collections["FaceCap take07"]
    assert sorted(o.name for o in coll.objects) == sorted(m.names)
    assert (scene.frame_start, scene.frame_end, scene.render.fps) == (11, 40, 50)
    frames, values = anim.read_curves(bpy.data.objects["lipT"], [("location", i) for i in range(3)])
    np.testing.assert_array_equal(frames, m.frames[m.visible[:, 2]])
    np.testing.assert_allclose(values, m.positions[m.visible[:, 2], 2] * 1e-3, atol=1e-6)
    settings = scene.facecap
    assert settings.marker_collection == coll and len(settings.markers) == 4
    back = take.markers_from_collection(settings)
    np.testing.assert_allclose(back.positions, m.to_units("m").positions, atol=1e-6, equal_nan=True)
    if ext != "trc":  # TRC has no segments
        names = sorted((t.name, t.frame) for t in scene.timeline_markers)
        assert names == [("posed_happy", 25), ("posed_happy end", 35), ("posed_neutral", 12),
                         ("posed_neutral end", 20)]
        assert (settings.neutral_first, settings.neutral_last) == (12, 20)


def test_import_options_units_axis_and_drop(empty_scene, tmp_path):
    m = make_take()
    write_markers(tmp_path / "a.csv", m)
    assert bpy.ops.facecap.import_csv(directory=str(tmp_path), files=[{"name": "a.csv"}], units="bu",
                                      unit_scale=0.01, up_axis="Y", fps=25.0) == {"FINISHED"}
    _, values = anim.read_curves(bpy.data.objects["browL"], [("location", i) for i in range(3)])
    x, y, z = m.positions[0, 0] * 0.01
    np.testing.assert_allclose(values[0], [x, -z, y], atol=1e-6)
    assert bpy.context.scene.render.fps == 25


def test_bad_file_is_reported_and_cancelled(empty_scene, tmp_path):
    bad = tmp_path / "bad.c3d"
    bad.write_bytes(b"\x02\x50" + b"\x00" * 100)
    with pytest.raises(RuntimeError, match=r"bad\.c3d: truncated C3D header"):
        bpy.ops.facecap.import_c3d(filepath=str(bad))
    assert not [c for c in bpy.data.collections if c.name.startswith("FaceCap")]


def test_file_handlers_and_menu_are_registered():
    assert bpy.types.FileHandler.bl_rna_get_subclass_py("FACECAP_FH_c3d") is not None
    assert hasattr(bpy.ops.facecap, "import_trc")
    draw_funcs = getattr(bpy.types.TOPBAR_MT_file_import.draw, "_draw_funcs", [])
    assert importers.menu_func_import in draw_funcs
