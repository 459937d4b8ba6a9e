"""Takes that already live in the scene: animated empties and movie-clip tracks."""

import bpy
import numpy as np
import pytest

from facecap.facecap_addon.scene import anim, take
from facecap.facecap_addon.scene.scene_sources import markers_from_clip, markers_from_empties
from facecap.solvers import FacecapError


def keyed_empty(name, values, frames):
    obj = bpy.data.objects.new(name, None)
    bpy.context.scene.collection.objects.link(obj)
    anim.new_action_with_curves(obj, name=name, curves=[("location", i) for i in range(3)], frames=frames, values=values)
    return obj


def test_selected_empties_become_a_take(empty_scene):
    frames = np.arange(1, 41, dtype=float)
    rng = np.random.default_rng(0)
    truth = rng.normal(size=(40, 3, 3)) * 0.01
    truth[10:14, 1] = np.nan  # unkeyed frames are gaps
    objs = [keyed_empty(n, truth[:, i], frames) for i, n in enumerate(["headA", "lip", "brow"])]
    for o in objs:
        o.select_set(True)
    bpy.context.view_layer.objects.active = objs[0]
    assert bpy.ops.facecap.use_selected_empties() == {"FINISHED"}
    s = bpy.context.scene.facecap
    assert s.take_name == "headA" and len(s.markers) == 3 and s.markers["headA"].stable
    back = take.markers_from_collection(s)
    order = [back.names.index(n) for n in ("headA", "lip", "brow")]
    np.testing.assert_allclose(back.positions[:, order], truth, atol=1e-6, equal_nan=True)
    assert objs[0].users_collection[0].name == "Scene Collection" or len(objs[0].users_collection) == 2


def test_parented_or_unkeyed_empties_are_refused(empty_scene):
    a = keyed_empty("a", np.zeros((3, 3)), np.arange(1.0, 4.0))
    b = bpy.data.objects.new("b", None)
    bpy.context.scene.collection.objects.link(b)
    with pytest.raises(FacecapError, match=r"\['b'\] have no location keys"):
        markers_from_empties([a, b], fps=60)
    a.parent = b
    with pytest.raises(FacecapError, match=r"\['a'\] have a parent"):
        markers_from_empties([a], fps=60)


def _clip(tmp_path, width=320, height=240, frames=20):
    cv2 = pytest.importorskip("cv2")
    for i in range(1, frames + 1):
        img = np.full((height, width, 3), 40 + 5 * i, np.uint8)
        cv2.imwrite(str(tmp_path / f"frame_{i:04d}.png"), img)
    clip = bpy.data.movieclips.load(str(tmp_path / "frame_0001.png"))
    return clip


def test_clip_tracks_are_read_in_pixels_top_left(empty_scene, tmp_path):
    clip = _clip(tmp_path)
    width, height = clip.size
    assert (width, height) == (320, 240)
    track = clip.tracking.tracks.new(name="lip", frame=1)
    for f in range(1, 11):
        track.markers.insert_frame(f, co=(0.25 + 0.01 * f, 0.75))
    track.markers.find_frame(5).mute = True
    other = clip.tracking.tracks.new(name="brow", frame=3)
    other.markers.insert_frame(3, co=(0.5, 0.5))
    m = markers_from_clip(clip, fallback_fps=24)
    assert m.fps == 24
    assert m.units == "px" and m.dim == 2 and m.names == ("lip", "brow")
    row = list(m.frames).index(2)
    np.testing.assert_allclose(m.positions[row, 0], [(0.25 + 0.02) * 320, (1 - 0.75) * 240], atol=1e-3)
    assert np.isnan(m.positions[list(m.frames).index(5), 0]).all()  # disabled marker = gap
    assert np.isnan(m.positions[row, 1]).all()  # no marker on that frame = gap
    bpy.context.scene.active_clip = clip
    assert bpy.ops.facecap.import_clip_tracks() == {"FINISHED"}
    assert bpy.context.scene.facecap.take_name == "frame_0001"


def test_clean_markers_makes_a_new_take_and_keeps_the_original(empty_scene):
    frames = np.arange(1, 121, dtype=float)
    t = frames / 60
    truth = np.stack([np.stack([0.01 * np.sin(2 * t + i), 0.01 * np.cos(3 * t), 0.002 * i + 0 * t], 1) for i in range(4)], 1)
    gappy = truth.copy()
    gappy[40:45, 2] = np.nan
    objs = [keyed_empty(f"m{i}", gappy[:, i], frames) for i in range(4)]
    for o in objs:
        o.select_set(True)
    bpy.context.view_layer.objects.active = objs[0]
    bpy.ops.facecap.use_selected_empties(take_name="take")
    s = bpy.context.scene.facecap
    original = s.marker_collection
    assert bpy.ops.facecap.clean_markers(fill_spline=8) == {"FINISHED"}
    assert s.marker_collection != original and s.take_name == "take clean"
    cleaned = take.markers_from_collection(s)
    np.testing.assert_allclose(cleaned.positions[40:45, cleaned.names.index("m2")], truth[40:45, 2], atol=1e-4)
    _, raw = anim.read_curves(objs[2], [("location", 0)])
    assert np.isnan(raw).sum() == 0 and raw.shape[0] == 115  # the original empty still lacks those 5 keys
