# SPDX-License-Identifier: GPL-3.0-or-later
"""facecap_addon.scene.anim: bulk action writing/reading on Blender 4.2 LTS through 5.0."""

import bpy
import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from facecap.facecap_addon.scene import anim
from facecap.solvers.errors import FacecapError

pytestmark = pytest.mark.blender

SHAPES = ("jawOpen", "mouthSmile_L", "browInnerUp")


def _path(shape):
    return f'key_blocks["{shape}"].value'


CURVES = [(_path(s), 0) for s in SHAPES]


@pytest.fixture
def face():
    """A one-triangle mesh with a basis and three shape keys, linked to the scene."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    mesh = bpy.data.meshes.new("face")
    mesh.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [], [(0, 1, 2)])
    obj = bpy.data.objects.new("face", mesh)
    bpy.context.scene.collection.objects.link(obj)
    obj.shape_key_add(name="Basis")
    for i, shape in enumerate(SHAPES):
        block = obj.shape_key_add(name=shape, from_mix=False)
        # Each shape moves vertex 0 along its own axis by 1 unit.
        block.data[0].co = tuple(1.0 if axis == i else 0.0 for axis in range(3))
    yield obj
    bpy.ops.wm.read_factory_settings(use_empty=True)


def _take(n_frames=10, seed=0):
    rng = np.random.default_rng(seed)
    frames = np.arange(1, n_frames + 1, dtype=np.float64)
    values = rng.uniform(0.0, 1.0, size=(n_frames, len(SHAPES)))
    return frames, values


def test_written_keys_read_back_equal(face):
    key = face.data.shape_keys
    frames, values = _take()
    action = anim.new_action_with_curves(
        key, name="take01", curves=CURVES, frames=frames, values=values
    )
    assert key.animation_data.action == action
    got_frames, got_values = anim.read_curves(key, CURVES)
    assert_allclose(got_frames, frames, atol=1e-6)
    assert_allclose(got_values, values, atol=1e-6)


def test_one_key_per_frame_per_shape_and_interpolation(face):
    key = face.data.shape_keys
    frames, values = _take(n_frames=25)
    action = anim.new_action_with_curves(
        key, name="take01", curves=CURVES, frames=frames, values=values, group="facecap"
    )
    fcurves = anim.action_fcurves(action, key)
    assert sorted((fc.data_path, fc.array_index) for fc in fcurves) == sorted(CURVES)
    for fc in fcurves:
        assert len(fc.keyframe_points) == frames.size
        assert {kp.interpolation for kp in fc.keyframe_points} == {"LINEAR"}
        assert fc.group is not None and fc.group.name == "facecap"


def test_nan_samples_are_skipped(face):
    key = face.data.shape_keys
    frames, values = _take(n_frames=8)
    values[[2, 5], 0] = np.nan
    values[:, 2] = np.nan  # a curve with no key at all gets no F-curve
    action = anim.new_action_with_curves(
        key, name="gaps", curves=CURVES, frames=frames, values=values
    )
    by_path = {fc.data_path: fc for fc in anim.action_fcurves(action, key)}
    assert len(by_path[_path("jawOpen")].keyframe_points) == 6
    assert len(by_path[_path("mouthSmile_L")].keyframe_points) == 8
    assert _path("browInnerUp") not in by_path
    got_frames, got_values = anim.read_curves(key, CURVES)
    assert_array_equal(got_frames, frames)
    assert_array_equal(np.isnan(got_values), np.isnan(values))
    assert_allclose(got_values, values, atol=1e-6, equal_nan=True)


def test_sampled_curves_read_back_as_keys_do(face):
    """Sampled curves (the solve's diagnostics): one sample per whole frame over the curve's range,
    NaN where it has no value; read back, evaluated and saved like keys."""
    key = face.data.shape_keys
    frames = np.array([3.0, 4.0, 5.0, 8.0, 9.0, 12.0])  # frames 6, 7, 10, 11 missing
    rng = np.random.default_rng(1)
    values = rng.uniform(0.0, 1.0, size=(frames.size, len(SHAPES)))
    values[[0, 4], 1] = np.nan
    action = anim.new_action_with_curves(key, name="diag", curves=CURVES, frames=frames, values=values,
                                         sampled=[False, True, True])
    by_path = {fc.data_path: fc for fc in anim.action_fcurves(action, key)}
    assert len(by_path[_path(SHAPES[0])].keyframe_points) == frames.size
    for shape, (first, last) in ((SHAPES[1], (4, 12)), (SHAPES[2], (3, 12))):
        fc = by_path[_path(shape)]
        assert len(fc.keyframe_points) == 0 and len(fc.sampled_points) == last - first + 1
        co = np.empty(2 * len(fc.sampled_points), dtype=np.float32)
        fc.sampled_points.foreach_get("co", co)
        assert_array_equal(co[0::2], np.arange(first, last + 1))
    got_frames, got_values = anim.read_curves(key, CURVES, action=action)
    assert_array_equal(got_frames, frames)
    assert_allclose(got_values, values, atol=1e-6)  # NaN where no value, as with keys
    fc = by_path[_path(SHAPES[2])]
    assert fc.evaluate(8.0) == pytest.approx(values[3, 2], abs=1e-6)
    assert np.isnan(fc.evaluate(7.0))  # a missing frame has no value (keys would interpolate)


def test_sampled_needs_whole_frames_else_keys(face):
    key = face.data.shape_keys
    frames = np.array([1.0, 1.5, 2.0])
    values = np.full((3, len(SHAPES)), 0.25)
    action = anim.new_action_with_curves(key, name="half", curves=CURVES, frames=frames, values=values, sampled=True)
    for fc in anim.action_fcurves(action, key):
        assert len(fc.keyframe_points) == 3 and len(fc.sampled_points) == 0
    with pytest.raises(FacecapError, match="sampled"):
        anim.new_action_with_curves(key, name="bad", curves=CURVES, frames=frames, values=values, sampled=[True])


def test_read_curves_union_of_frames(face):
    key = face.data.shape_keys
    frames = np.array([1.0, 2.0, 3.0, 4.0])
    values = np.array([[0.1, np.nan, np.nan], [np.nan, 0.2, np.nan], [0.3, np.nan, np.nan],
                       [np.nan, np.nan, np.nan]])
    anim.new_action_with_curves(key, name="t", curves=CURVES, frames=frames, values=values)
    got_frames, got_values = anim.read_curves(key, CURVES + [(_path("missing"), 0)])
    assert_array_equal(got_frames, [1.0, 2.0, 3.0])
    assert got_values.shape == (3, 4)
    assert_allclose(got_values[:, :3], values[:3], atol=1e-6, equal_nan=True)
    assert np.all(np.isnan(got_values[:, 3]))


def test_read_curves_without_action_is_empty(face):
    frames, values = anim.read_curves(face.data.shape_keys, CURVES)
    assert frames.shape == (0,)
    assert values.shape == (0, len(CURVES))


def test_object_evaluates_keyed_value_after_frame_set(face):
    key = face.data.shape_keys
    frames, values = _take(n_frames=12, seed=3)
    anim.new_action_with_curves(key, name="take01", curves=CURVES, frames=frames, values=values)
    scene = bpy.context.scene
    for frame_index in (0, 4, 11):
        scene.frame_set(int(frames[frame_index]))
        for column, shape in enumerate(SHAPES):
            expected = values[frame_index, column]
            assert key.key_blocks[shape].value == pytest.approx(expected, abs=1e-6)
        # The evaluated mesh moves vertex 0 by the weights (each shape is a unit offset on an axis).
        evaluated = face.evaluated_get(bpy.context.evaluated_depsgraph_get())
        co = np.array(evaluated.data.vertices[0].co)
        assert_allclose(co, values[frame_index], atol=1e-5)
    # Linear interpolation between keys.
    scene.frame_set(4, subframe=0.5)
    expected = 0.5 * (values[3] + values[4])
    got = [key.key_blocks[shape].value for shape in SHAPES]
    assert_allclose(got, expected, atol=1e-5)


def test_second_call_makes_new_action_and_keeps_first(face, tmp_path):
    key = face.data.shape_keys
    frames, first_values = _take(seed=1)
    _, second_values = _take(seed=2)
    first = anim.new_action_with_curves(
        key, name="take01", curves=CURVES, frames=frames, values=first_values
    )
    second = anim.new_action_with_curves(
        key, name="take01", curves=CURVES, frames=frames, values=second_values
    )
    assert second != first
    assert first.name == "take01"
    assert second.name == "take01.001"
    assert key.animation_data.action == second
    assert first.use_fake_user

    blend = tmp_path / "takes.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    bpy.ops.wm.open_mainfile(filepath=str(blend))

    key = bpy.data.objects["face"].data.shape_keys
    assert key.animation_data.action.name == "take01.001"
    assert {"take01", "take01.001"} <= set(bpy.data.actions.keys())
    _, got = anim.read_curves(key, CURVES)
    assert_allclose(got, second_values, atol=1e-6)
    # The first take is intact: reassign it and read it back.
    first = bpy.data.actions["take01"]
    by_path = {fc.data_path: fc for fc in anim.action_fcurves(first)}
    for column, (path, _index) in enumerate(CURVES):
        co = np.empty(2 * len(by_path[path].keyframe_points), dtype=np.float32)
        by_path[path].keyframe_points.foreach_get("co", co)
        assert_allclose(co[1::2], first_values[:, column], atol=1e-6)


def test_previous_user_action_not_modified(face):
    """An action the animator made stays as it was (curves and keys) after a facecap take."""
    key = face.data.shape_keys
    frames, values = _take(seed=4)
    manual = anim.new_action_with_curves(
        key, name="manual", curves=CURVES[:1], frames=frames, values=values[:, :1]
    )
    manual.use_fake_user = False
    anim.new_action_with_curves(key, name="take", curves=CURVES, frames=frames, values=values)
    assert manual.use_fake_user
    fcurves = anim.action_fcurves(manual)
    assert [fc.data_path for fc in fcurves] == [CURVES[0][0]]
    assert len(fcurves[0].keyframe_points) == frames.size


def test_object_level_action(face):
    frames = np.array([1.0, 10.0])
    values = np.array([[0.0, 1.0], [2.0, 3.0]])
    curves = [("location", 0), ("location", 2)]
    action = anim.new_action_with_curves(
        face, name="move", curves=curves, frames=frames, values=values
    )
    assert face.animation_data.action == action
    if anim.LAYERED_ACTIONS:
        assert face.animation_data.action_slot.target_id_type == "OBJECT"
    bpy.context.scene.frame_set(10)
    assert tuple(face.location) == pytest.approx((2.0, 0.0, 3.0), abs=1e-6)


def test_unique_action_name(face):
    assert anim.unique_action_name("take01") == "take01"
    bpy.data.actions.new("take01")
    assert anim.unique_action_name("take01") == "take01.001"
    bpy.data.actions.new("take01.001")
    assert anim.unique_action_name("take01") == "take01.002"
    with pytest.raises(FacecapError, match="base"):
        anim.unique_action_name("")


@pytest.mark.parametrize(
    ("frames", "values", "match"),
    [
        (np.arange(3.0), np.zeros((3, 2)), r"`values` must have shape \(F, C\) = \(3, 3\)"),
        (np.array([1.0, 1.0, 2.0]), np.zeros((3, 3)), "strictly increasing"),
        (np.array([1.0, np.nan, 2.0]), np.zeros((3, 3)), "finite"),
        (np.zeros((3, 1)), np.zeros((3, 3)), r"`frames` must have shape \(F,\)"),
    ],
)
def test_bad_input_raises_and_creates_nothing(face, frames, values, match):
    with pytest.raises(FacecapError, match=match):
        anim.new_action_with_curves(
            face.data.shape_keys, name="bad", curves=CURVES, frames=frames, values=values
        )
    assert len(bpy.data.actions) == 0


def test_unknown_interpolation_raises(face):
    frames, values = _take()
    with pytest.raises(FacecapError, match="interpolation"):
        anim.new_action_with_curves(
            face.data.shape_keys, name="t", curves=CURVES, frames=frames, values=values,
            interpolation="SMOOTH",
        )
