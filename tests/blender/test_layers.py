"""Solve layer vs the animator's layer: edits survive re-solves; the layered value matches Blender."""

import sys
from pathlib import Path

import bpy
import numpy as np
import pytest

from scene_fixtures import build_character

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))
from synthetic_face import make_basis  # noqa: E402

from facecap.facecap_addon.scene import anim, layers  # noqa: E402
from facecap.solvers.io.csv import write_markers_csv  # noqa: E402
from facecap.solvers.tools.synthetic.synth import synthesize_take  # noqa: E402

N_FRAMES = 160


@pytest.fixture
def solved(empty_scene, tmp_path):
    basis, stable = make_basis()
    rng = np.random.default_rng(3)
    weights = np.clip(rng.uniform(-0.4, 1.0, size=(N_FRAMES, basis.n_shapes)), 0, 1)
    weights[:40] = 0.0
    synth = synthesize_take(basis, weights, stable=stable, noise_sigma=0.0, gap_fraction=0.0, seed=5)
    path = tmp_path / "take01.csv"
    write_markers_csv(path, synth.markers)
    obj = build_character(basis)
    assert bpy.ops.facecap.import_markers(filepath=str(path), units="mm", fps=60.0) == {"FINISHED"}
    s = bpy.context.scene.facecap
    s.target = obj
    bpy.ops.facecap.set_neutral(first=1, last=30)
    assert bpy.ops.facecap.solve() == {"FINISHED"}
    return obj, basis.shape_names


def _evaluated(obj, names, frames):
    scene = bpy.context.scene
    out = np.empty((len(frames), len(names)))
    for i, f in enumerate(frames):
        scene.frame_set(int(f))
        out[i] = [obj.data.shape_keys.key_blocks[n].value for n in names]
    return out


def _key_edit(obj, name, frame, value):
    """Key ``value`` on the animator layer as the UI does (Blender remaps it through the NLA)."""
    bpy.context.scene.frame_set(frame)
    block = obj.data.shape_keys.key_blocks[name]
    block.value = value
    assert block.keyframe_insert("value", frame=frame)


def test_first_solve_sets_up_the_layers(solved):
    obj, names = solved
    key = obj.data.shape_keys
    track = layers.solve_track(key)
    assert track is not None and track.lock and len(track.strips) == 1
    assert key.animation_data.action is None and key.animation_data.action_blend_type == "ADD"
    assert layers.solved_action(key)[layers.SOLVE_TAG] == "take01"


@pytest.mark.parametrize("mode", ["ADD", "COMBINE", "REPLACE", "MULTIPLY", "SUBTRACT"])
def test_layered_values_match_blender(solved, mode):
    obj, names = solved
    key = obj.data.shape_keys
    key.animation_data.action_blend_type = mode
    _key_edit(obj, names[0], 80, 0.9)
    _key_edit(obj, names[0], 100, 0.2)
    _key_edit(obj, names[3], 90, 0.5)
    key.animation_data.action_influence = 0.7
    frames = np.array([50, 80, 85, 90, 100, 130])
    solve, final = layers.layer_values(key, list(names), frames)
    np.testing.assert_allclose(final, _evaluated(obj, names, frames), atol=2e-6)
    np.testing.assert_allclose(solve[:, 5], final[:, 5])  # a shape with no edit curve is the solve


def test_manual_keys_survive_three_resolves(solved):
    obj, names = solved
    key = obj.data.shape_keys
    _key_edit(obj, names[2], 70, 0.95)
    _key_edit(obj, names[2], 60, layers.layer_values(key, [names[2]], [60])[0][0, 0])  # anchor at the solve: no change
    edits = key.animation_data.action
    keys_before = [tuple(k.co) for fc in anim.action_fcurves(edits, key) for k in fc.keyframe_points]
    np.testing.assert_allclose(layers.edited_frames(key, list(names)), [70])
    s = bpy.context.scene.facecap
    solves = {layers.solved_action(key).name}
    for reg in (0.01, 0.02, 0.03):
        s.regularisation = reg
        assert bpy.ops.facecap.solve() == {"FINISHED"}
        solves.add(layers.solved_action(key).name)
        assert key.animation_data.action == edits
        assert [tuple(k.co) for fc in anim.action_fcurves(edits, key) for k in fc.keyframe_points] == keys_before
    assert len(solves) == 4 and all(n in bpy.data.actions for n in solves)
    assert len(layers.solve_track(key).strips) == 1


def test_a_solve_assigned_by_an_older_version_moves_off_the_animator_layer(solved):
    obj, names = solved
    key = obj.data.shape_keys
    old = layers.solved_action(key)
    key.animation_data.action = old  # as facecap 0.1 left files: the solve was the active action
    assert bpy.ops.facecap.solve() == {"FINISHED"}
    assert key.animation_data.action is None and old.use_fake_user


def test_a_locked_shape_keeps_the_animators_keys_through_resolves(solved):
    obj, names = solved
    key = obj.data.shape_keys
    shape = names[4]
    _key_edit(obj, shape, 60, 0.8)
    _key_edit(obj, shape, 120, 0.1)
    frames = np.arange(1, N_FRAMES + 1, dtype=float)
    seen = layers.layer_values(key, [shape], frames)[1][:, 0]
    s = bpy.context.scene.facecap
    assert bpy.ops.facecap.refresh_shapes() == {"FINISHED"}
    next(item for item in s.shapes if item.name == shape).lock = True
    for reg in (0.002, 0.004):
        s.regularisation = reg
        assert bpy.ops.facecap.solve() == {"FINISHED"}
        np.testing.assert_allclose(layers.layer_values(key, [shape], frames)[1][:, 0], seen, atol=1e-6)
        np.testing.assert_allclose(_evaluated(obj, [shape], [60, 120])[:, 0], [0.8, 0.1], atol=1e-5)
