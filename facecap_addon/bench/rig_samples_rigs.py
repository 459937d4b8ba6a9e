"""Bone-driven test faces on the sample character: a small hand-made armature, and a Rigify face
generated headless from the metarig that ships with Blender (see ``rig_samples``)."""

import addon_utils
import bpy
import numpy as np
from mathutils import Matrix

from ...solvers.errors import FacecapError
from ...solvers.transforms import fit_similarity
from .rig_samples import bone_only_copy, face_lines, marker_points, skin

BONE_FACE = "FaceBoneRig"
#: (bone, marker it sits on, parent): the bone-only face; each bone points 1 cm out of the face.
FACE_BONES = (
    ("lip_upper", "lip_upper_C", "head"), ("lip_lower", "lip_lower_C", "jaw"),
    ("lip_corner.L", "mouth_corner_L", "head"), ("lip_corner.R", "mouth_corner_R", "head"),
    ("brow_inner.L", "brow_inner_L", "head"), ("brow_inner.R", "brow_inner_R", "head"),
    ("brow_outer.L", "brow_outer_L", "head"), ("brow_outer.R", "brow_outer_R", "head"),
    ("lid_upper.L", "eyelid_upper_L", "head"), ("lid_upper.R", "eyelid_upper_R", "head"),
    ("lid_lower.L", "eyelid_lower_L", "head"), ("lid_lower.R", "eyelid_lower_R", "head"),
    ("cheek.L", "cheek_L", "head"), ("cheek.R", "cheek_R", "head"),
)
JAW_HINGE = (0.0, 0.012, -0.010)


def _edit(armature):
    bpy.context.view_layer.objects.active = armature
    bpy.ops.object.mode_set(mode="EDIT")
    return armature.data.edit_bones


def build_bone_face(mesh):
    """(face, armature): a shape-key-free copy of ``mesh`` skinned to ``FACE_BONES`` plus a jaw."""
    points = marker_points(mesh)
    face = bone_only_copy(mesh, mesh.name + "Bones")
    arm = bpy.data.objects.new(BONE_FACE, bpy.data.armatures.new(BONE_FACE))
    for coll in mesh.users_collection:
        coll.objects.link(arm)
    arm.matrix_world = mesh.matrix_world
    eb = _edit(arm)
    head = eb.new("head")
    head.head, head.tail = (0.0, 0.03, -0.03), (0.0, 0.03, 0.09)
    jaw = eb.new("jaw")
    jaw.head, jaw.tail, jaw.parent = JAW_HINGE, tuple(points["chin_C"]), head
    for name, marker, parent in FACE_BONES:
        b = eb.new(name)
        p = points[marker]
        b.head, b.tail, b.parent = tuple(p), tuple(p + np.array([0.0, -0.01, 0.0])), eb[parent]
    bpy.ops.object.mode_set(mode="OBJECT")
    for pb in arm.pose.bones:
        pb.rotation_mode = "XYZ"
    mouth, eye = face_lines(points)
    skin(face, arm, mouth_z=mouth, eye_z=eye, fallback="head")
    face.parent = arm
    return face, arm


def bone_face_controls():
    """``[rig] controls`` of the bone-only face: every face bone's location, the jaw's X rotation."""
    specs = [{"object": BONE_FACE, "path": f'pose.bones["{b}"].location'} for b, _, _ in FACE_BONES]
    return specs + [{"object": BONE_FACE, "path": 'pose.bones["jaw"].rotation', "axes": [0]}]


#: Metarig landmarks (bone, "head" / "tail") and the sample character's marker at the same place.
RIGIFY_LANDMARKS = (
    ("lip.T.L", "head", "lip_upper_C"), ("lip.B.L", "head", "lip_lower_C"),
    ("lip.T.L.001", "tail", "mouth_corner_L"), ("lip.T.R.001", "tail", "mouth_corner_R"),
    ("lid.T.L", "head", "eye_outer_L"), ("lid.T.R", "head", "eye_outer_R"),
    ("brow.T.L.002", "head", "brow_mid_L"), ("brow.T.R.002", "head", "brow_mid_R"), ("chin", "head", "chin_C"),
)
#: Metarig bones kept besides the head's subtree (the neck chain the head rig hangs on).
RIGIFY_KEEP = ("spine.004", "spine.005", "spine.006")


def build_rigify_face(mesh, *, say=None):
    """(face, rig): Rigify's face fitted to ``mesh`` and generated; a shape-key-free copy of
    ``mesh`` skinned to its deforming bones. Needs the Rigify add-on that ships with Blender."""
    return _build_rigify(mesh, say=say, head_only=True)


def build_rigify_human(mesh, *, say=None):
    """(face, rig): the whole Rigify human (Add > Armature > Human, 700 bones once generated) with
    its face fitted to ``mesh``, and a copy of ``mesh`` parented to it with automatic weights, as a
    user makes it."""
    return _build_rigify(mesh, say=say, head_only=False)


def _build_rigify(mesh, *, say=None, head_only=True):
    if addon_utils.check("rigify")[1] is False and not addon_utils.enable("rigify", default_set=True):
        raise FacecapError("the Rigify add-on could not be enabled (it ships with Blender as 'rigify')")
    points = marker_points(mesh)
    bpy.ops.object.select_all(action="DESELECT")
    bpy.ops.object.armature_human_metarig_add()
    meta = bpy.context.active_object
    meta.matrix_world = np.eye(4).tolist()
    eb = _edit(meta)
    if head_only:
        keep = {b.name for b in meta.data.bones["spine.006"].children_recursive} | set(RIGIFY_KEEP)
        for b in list(eb):
            if b.name not in keep:
                eb.remove(b)
        eb["spine.004"].use_connect, eb["spine.004"].parent = False, None
    landmarks = np.array([getattr(eb[b], end) for b, end, _ in RIGIFY_LANDMARKS], dtype=np.float64)
    bpy.ops.object.mode_set(mode="OBJECT")
    if head_only:
        meta.pose.bones["spine.004"].rigify_parameters.connect_chain = False
    target = np.array([points[m] for _, _, m in RIGIFY_LANDMARKS])
    sim = fit_similarity(target, landmarks)  # the face's own space -> the metarig's (at the origin)
    if say:
        say(f"rigify: the face placed on the metarig (scale {sim.scale:.3f}); generating")
    bpy.ops.pose.rigify_generate()
    rig = meta.data.rigify_target_rig
    if rig is None:
        raise FacecapError("Rigify generated no rig")
    meta.hide_set(True)
    face = bone_only_copy(mesh, mesh.name + ("Rigify" if head_only else "Human"), keep_keys=True)
    M = np.eye(4)  # the face keeps its own units in its data; its object transform puts it on the rig
    M[:3, :3], M[:3, 3] = sim.scale * np.asarray(sim.rotation), sim.translation
    if head_only:
        face.parent = rig
        face.matrix_parent_inverse = np.eye(4).tolist()
        face.matrix_world = Matrix(M.tolist())
        bpy.context.view_layer.update()
        mouth, eye = face_lines(points)
        skin(face, rig, mouth_z=mouth, eye_z=eye, fallback="DEF-spine.006", sigma=0.008)
        return face, rig
    face.matrix_world = Matrix(M.tolist())
    bpy.context.view_layer.update()
    bpy.ops.object.select_all(action="DESELECT")
    face.select_set(True)
    rig.select_set(True)
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.parent_set(type="ARMATURE_AUTO")  # Ctrl-P > With Automatic Weights
    return face, rig
