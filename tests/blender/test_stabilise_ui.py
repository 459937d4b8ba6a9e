"""Issue 4 from the sidebar: suggest stable markers, neutral modes, master T-pose in the .blend,
head motion keyed onto a character object or bone, unreliable frames shown."""

import bpy
import numpy as np
import pytest

from scene_fixtures import draw_panel
from test_operators import _import, _solved_values, take  # noqa: F401  (fixture)

from facecap.facecap_addon.scene import anim, take as take_mod
from facecap.solvers.capture.stabilise import stabilise_rigid


def _stable_names(s):
    return sorted(m.name for m in s.markers if m.stable)


def test_suggest_stable_markers_ticks_them_and_shows_scores(take):
    _import(take)
    s = bpy.context.scene.facecap
    for m in s.markers:
        m.stable = False
    assert bpy.ops.facecap.suggest_stable() == {"FINISHED"}
    assert _stable_names(s) == sorted(take["stable"])
    assert all(m.stable_score >= 0 for m in s.markers)
    assert max(m.stable_score for m in s.markers if m.stable) < min(m.stable_score for m in s.markers if not m.stable)
    assert s.stable_gap >= 2.0


def test_head_motion_keyed_on_an_object_reproduces_the_raw_markers(take):
    _import(take)
    s = bpy.context.scene.facecap
    head = bpy.data.objects.new("CharacterHead", None)
    bpy.context.scene.collection.objects.link(head)
    s.head_target = head
    assert bpy.ops.facecap.stabilise() == {"FINISHED"}
    markers = take_mod.markers_from_collection(s)
    stab = stabilise_rigid(markers, take["stable"], reference_frames=(s.neutral_first, s.neutral_last))
    pivot = np.array(head["facecap_head_pivot"])
    frames, values = anim.read_curves(head, [("location", i) for i in range(3)] + [("rotation_euler", i) for i in range(3)])
    assert frames.size == markers.n_frames
    euler = values[:, 3:]
    assert np.abs(np.diff(euler, axis=0)).max() < np.pi / 2  # unwrapped: no flips
    worst = 0.0
    for f in (1, 70, 150, 239):
        bpy.context.scene.frame_set(f)
        M = np.array(head.matrix_world)
        i = int(np.flatnonzero(markers.frames == f)[0])
        x = stab.markers.positions[i]
        raw = (x - pivot) @ M[:3, :3].T + pivot + M[:3, 3]
        ok = ~np.isnan(markers.positions[i, :, 0])
        worst = max(worst, np.abs(raw[ok] - markers.positions[i, ok]).max())
    print(f"head re-applied to the stabilised markers: max error {worst * 1e3:.4f} mm")
    assert worst < 1e-5  # float32 keys on a noise-free take
    fr, unreliable = anim.read_curves(head, [('["facecap_unreliable"]', 0)])
    assert fr.size == markers.n_frames and np.all(unreliable == 0)
    hf, _ = anim.read_curves(s.head_object, [('["facecap_unreliable"]', 0)])
    assert hf.size == markers.n_frames


def test_head_motion_keyed_on_a_bone(take):
    _import(take)
    s = bpy.context.scene.facecap
    arm = bpy.data.armatures.new("Rig")
    rig = bpy.data.objects.new("Rig", arm)
    bpy.context.scene.collection.objects.link(rig)
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.mode_set(mode="EDIT")
    bone = arm.edit_bones.new("head")
    bone.head, bone.tail = (0.0, 0.0, 1.5), (0.0, 0.1, 1.6)
    bpy.ops.object.mode_set(mode="OBJECT")
    s.head_target, s.head_bone = rig, "head"
    assert bpy.ops.facecap.stabilise() == {"FINISHED"}
    markers = take_mod.markers_from_collection(s)
    stab = stabilise_rigid(markers, take["stable"], reference_frames=(s.neutral_first, s.neutral_last))
    Rh = stab.head_rotations()
    B = np.array(arm.bones["head"].matrix_local)
    for f in (1, 120, 200):
        bpy.context.scene.frame_set(f)
        P = np.array(rig.pose.bones["head"].matrix)  # armature space
        i = int(np.flatnonzero(markers.frames == f)[0])
        np.testing.assert_allclose(P[:3, :3], Rh[i] @ B[:3, :3], atol=1e-5)


def test_neutral_modes_and_master_tpose_from_the_sidebar(take, tmp_path):
    _import(take)
    s = bpy.context.scene.facecap
    s.target = take["obj"]
    bpy.ops.facecap.set_neutral(first=1, last=50)
    assert bpy.ops.facecap.master_from_take() == {"FINISHED"}
    assert s.master_data and "frames 1-50" in s.master_source
    s.use_master = True
    s.landmarks = "m1*, m2*, m3*, m4*"
    s.regularisation = s.sparsity = s.symmetry = s.head_smoothing = s.smoothing_second = 0.0  # exact data, no priors
    assert bpy.ops.facecap.solve() == {"FINISHED"}
    names = take["basis"].shape_names
    err = _solved_values(take["obj"], names) - take["weights"]
    print(f"master T-pose from the sidebar: max error {np.abs(err).max():.2e}")
    assert np.abs(err).max() <= 1e-3  # the master is this take's own T-pose: same solve
    # the master is in the .blend and survives a save/reload
    path = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.open_mainfile(filepath=str(path))
    s = bpy.context.scene.facecap
    assert take_mod.master_markers(s).n_markers == take["basis"].n_markers
    s.use_master = False
    assert bpy.ops.facecap.detect_neutral() == {"FINISHED"} and s.neutral_mode == "DETECT"
    s.neutral_mode = "RANGES"
    s.neutral_end_first, s.neutral_end_last = 1, 40
    opts = take_mod.retarget_settings(s)
    assert opts.neutral_ranges == ((1, 50), (1, 40))


@pytest.mark.parametrize("mode", ["RANGE", "RANGES", "DETECT", "FILE"])
def test_stabilise_panel_draws_every_neutral_mode(take, mode):
    _import(take)
    s = bpy.context.scene.facecap
    s.neutral_mode = mode
    s.unreliable_frames = 3
    s.stable_gap = 1.5
    layout = draw_panel("FACECAP_PT_stabilise")
    assert ("operator", "facecap.suggest_stable") in layout.calls
    assert ("prop", "neutral_mode") in layout.calls and ("prop", "use_master") in layout.calls
    assert any(c[0] == "label" and c[1] and "unreliable" in c[1] for c in layout.calls)


def test_output_head_keys_the_solved_head_motion_on_the_character(take):
    """``[output] head`` / the sidebar's head target: key_weights (the CLI's keying step) keys it too."""
    import dataclasses

    from facecap.solvers.pipeline import retarget

    _import(take)
    s = bpy.context.scene.facecap
    s.target = take["obj"]
    bpy.ops.facecap.set_neutral(first=1, last=50)
    head = bpy.data.objects.new("CharHead", None)
    bpy.context.scene.collection.objects.link(head)
    head.location = (0.0, 0.0, 1.6)
    markers = take_mod.markers_from_collection(s)
    from facecap.facecap_addon.scene.scene_data import basis_from_object

    basis = basis_from_object(take["obj"], markers.names)
    settings = dataclasses.replace(take_mod.retarget_settings(s), head_target="CharHead")
    result = retarget(markers, basis, settings)
    take_mod.key_weights(take["obj"], result, "with_head")
    frames, loc = anim.read_curves(head, [("location", i) for i in range(3)])
    assert frames.size == markers.n_frames
    np.testing.assert_allclose(loc[0], (0.0, 0.0, 1.6), atol=1e-4)  # rest placement kept at the reference
    assert np.ptp(loc, axis=0).max() > 1e-3  # and the head moves


def test_stabilising_again_reuses_the_head_empty_and_its_action(take):
    """Issue 40: every Stabilise added another empty and action (FaceCap Head sample_take.001, ...). The take's
    head empty is re-keyed and its action replaced; another take gets its own; a user's object of that name is
    never taken over."""
    _import(take)
    s = bpy.context.scene.facecap
    name = f"FaceCap Head {s.take_name}"
    objects, actions = len(bpy.data.objects), len(bpy.data.actions)
    assert bpy.ops.facecap.stabilise() == {"FINISHED"}
    head = s.head_object
    assert head.name == name and head.animation_data.action.name == name
    first, _ = anim.read_curves(head, [("location", 0)])
    for _ in range(2):
        assert bpy.ops.facecap.stabilise() == {"FINISHED"}
    assert s.head_object == head and len(bpy.data.objects) == objects + 1 and len(bpy.data.actions) == actions + 1
    assert head.animation_data.action.name == name
    again, _ = anim.read_curves(head, [("location", 0)])
    assert np.array_equal(first, again)
    s.take_name = "another_take"
    assert bpy.ops.facecap.stabilise() == {"FINISHED"}
    assert s.head_object.name == "FaceCap Head another_take" and head.name == name  # the first take's kept
    mine = bpy.data.objects.new("FaceCap Head mine", None)  # a user's empty that happens to have the name
    bpy.context.scene.collection.objects.link(mine)
    s.take_name = "mine"
    assert bpy.ops.facecap.stabilise() == {"FINISHED"}
    assert s.head_object != mine and mine.animation_data is None
