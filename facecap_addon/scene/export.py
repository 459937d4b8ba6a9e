"""Delivery to game engines and DCCs: the character with its shape keys and the take's animation,
written as binary glTF (.glb) or FBX by Blender's own exporters.

What is written: the character mesh (its shape keys as morph targets / blend shapes) with one action
on its shape keys holding the *final* weights, the solve layer with the animator's layer on top
baked into one curve per shape (``layers.layer_values``: Blender's NLA blend), at every frame of
the solve; plus the head object (or the armature with the head bone) when it is keyed, with its
action. One animation (glTF) / take (FBX) named after the take.

The user's scene is not changed: the export works on copies in a temporary scene, and the
originals only lend their names (a game engine binds animation by name) for the duration of the
exporter's call; everything is put back and the copies removed, also when the exporter fails.
"""

import contextlib
import io
import logging
import os
from pathlib import Path

import bpy
import numpy as np

from ...solvers.errors import FacecapError
from ...solvers.io.files import atomic_path
from ...solvers.io.outputs import Output, check_outputs
from . import anim, layers
from .scene_data import shape_key_names

#: file suffix -> format
FORMATS = {".glb": "GLTF", ".fbx": "FBX"}
#: Where the exporters' own console lines go: debug lines of the package's Blender log (``facecap -v`` shows
#: them), as the command line does with Blender's other output (``headless/console.py``).
BLENDER_LOG = logging.getLogger(__name__.rsplit(".", 3)[0] + ".blender")


@contextlib.contextmanager
def exporter_lines_logged():
    """What an exporter prints (glTF: "ERROR Draco is not available because library could not be found" where
    Blender's Python module lacks the compression libraries, which facecap never asks for; "INFO: Starting glTF
    2.0 export") kept off the artist's console, as debug lines of ``BLENDER_LOG``, even when the export fails."""
    out = io.StringIO()
    try:
        with contextlib.redirect_stdout(out):
            yield
    finally:
        for line in out.getvalue().splitlines():
            if line.strip():
                BLENDER_LOG.debug(line.rstrip())


def export_take(obj, path, *, head_target="", fps=None, take_name=None):
    """Write ``obj`` with its shape keys and the take's final animation to ``path`` (.glb or .fbx).

    Parameters
    ----------
    obj : bpy.types.Object, a mesh whose shape keys carry a solve layer (``layers``)
    path : str or Path, ending in .glb (binary glTF) or .fbx; written atomically
    head_target : "Object" or "Armature:bone" ([output] head); included when it has an action
    fps : frames per second of the animation (default: the scene's)
    take_name : name of the animation / take (default: the solve's take name)

    Returns
    -------
    dict with ``path``, ``format``, ``frames`` (first, last), ``shapes`` and ``head`` (object name or None).

    Raises
    ------
    FacecapError when there is no solve to export or the suffix is not .glb / .fbx.
    """
    path = Path(os.path.expanduser(str(path)))
    fmt = FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise FacecapError(f"{path}: export to .glb (binary glTF) or .fbx; got '{path.suffix}'")
    # the output policy; replacing an existing file was chosen (the file browser, or the run's own checks)
    check_outputs([Output("the export", path, "glb" if path.suffix.lower() == ".glb" else "fbx")],
                  {"the open .blend": bpy.data.filepath or None}, overwrite=True)
    key = getattr(obj.data, "shape_keys", None) if obj is not None else None
    solve = None if key is None else layers.solved_action(key)
    if solve is None:
        raise FacecapError(f"'{getattr(obj, 'name', obj)}' has no solved take to export (solve it first)")
    names = list(shape_key_names(obj))
    frames = _solve_frames(key, names, solve)
    final = shown_values(key, names, frames)
    head = _head_object(head_target)
    scene = bpy.context.scene
    fps = float(fps) if fps else scene.render.fps / scene.render.fps_base
    take_name = take_name or solve.get(layers.SOLVE_TAG) or solve.name
    with _Copies(obj, head, take_name, fps, frames) as copies:
        copies.bake_shapes(names, frames, final)
        with atomic_path(path, suffix=path.suffix) as tmp:
            copies.write(tmp, fmt)
    return {"path": str(path), "format": fmt, "frames": (int(frames[0]), int(frames[-1])), "shapes": len(names),
            "head": None if head is None else head.name}


def shown_values(key, names, frames):
    """The weights (F, K) Blender shows at ``frames``: solve layer with the animator's layer
    (``layers.layer_values``), within each shape's slider range (Blender clamps the evaluated value)."""
    final = layers.layer_values(key, names, frames)[1]
    blocks = [key.key_blocks[n] for n in names]
    low = np.array([b.slider_min for b in blocks])
    high = np.array([b.slider_max for b in blocks])
    return np.clip(final, low, high)


def _solve_frames(key, names, solve):
    """Every whole frame from the solve's first to its last key."""
    keyed = anim.read_curves(key, [(layers.shape_path(n), 0) for n in names], action=solve)[0]
    if not keyed.size:
        raise FacecapError(f"the solve '{solve.name}' has no keys to export")
    return np.arange(np.floor(keyed[0]), np.ceil(keyed[-1]) + 1.0)


def _head_object(head_target):
    """The object ([output] head "Object" or "Armature:bone") that carries keyed head motion, or None."""
    if not head_target:
        return None
    obj = bpy.data.objects.get(head_target.partition(":")[0])
    if obj is None or obj.animation_data is None or obj.animation_data.action is None:
        return None
    return obj


class _Copies:
    """Copies of the character (and head) in a temporary scene, under the originals' names while
    exporting; ``__exit__`` removes them and gives the names back."""

    def __init__(self, obj, head, take_name, fps, frames):
        self.originals = [o for o in (head, obj) if o is not None]
        self.obj, self.take_name, self.fps, self.frames = obj, take_name, fps, frames
        self.made = []  # every ID created here, removed at the end
        self.renamed = []  # (ID, its own name)

    def __enter__(self):
        self.scene = self._new(bpy.data.scenes.new(self.take_name))
        render = self.scene.render
        render.fps, render.fps_base = _fps_pair(self.fps)
        self.scene.frame_start, self.scene.frame_end = int(self.frames[0]), int(self.frames[-1])
        self.copies = {}
        for original in self.originals:
            copy = self._new(original.copy())
            if original.type == "MESH":
                copy.data = self._new(original.data.copy())  # its own shape keys
                if copy.data.shape_keys is not None:
                    copy.data.shape_keys.animation_data_clear()
            if copy.animation_data is not None and original.animation_data.action is not None:
                anim.ensure_animation_data(copy)  # the head keeps its action; the NLA stack is not exported
                for track in list(copy.animation_data.nla_tracks):
                    copy.animation_data.nla_tracks.remove(track)
            self.scene.collection.objects.link(copy)
            self.copies[original] = copy
        for original, copy in self.copies.items():
            self._place(original, copy)
        return self

    def _new(self, id_data):
        self.made.append(id_data)
        return id_data

    def _place(self, original, copy):
        """Parent the copy to the copy of its parent, or keep its world placement without one;
        armature modifiers follow the copied armature."""
        parent = self.copies.get(original.parent)
        if parent is not None:
            copy.parent = parent
        elif original.parent is not None:
            copy.parent = None
            copy.matrix_world = original.matrix_world.copy()
        for modifier in copy.modifiers:
            if modifier.type == "ARMATURE" and modifier.object in self.copies:
                modifier.object = self.copies[modifier.object]

    def bake_shapes(self, names, frames, values):
        """One action on the copied shape keys: the final weights (F, K) at ``frames``."""
        key = self.copies[self.obj].data.shape_keys
        curves = [(layers.shape_path(n), 0) for n in names]
        action = anim.new_action_with_curves(key, name=self.take_name, curves=curves, frames=frames, values=values,
                                             group="FaceCap Weights")
        self.made.append(action)

    def write(self, path, fmt):
        self._borrow_names()
        try:
            with bpy.context.temp_override(scene=self.scene), exporter_lines_logged():
                if fmt == "GLTF":
                    _call(bpy.ops.export_scene.gltf, filepath=str(path), export_format="GLB", use_active_scene=True,
                          export_animations=True, export_morph=True, export_morph_animation=True,
                          export_animation_mode="ACTIVE_ACTIONS",
                          export_nla_strips_merged_animation_name=self.take_name,
                          export_force_sampling=True, export_optimize_animation_size=False, export_apply=False)
                else:
                    _call(bpy.ops.export_scene.fbx, filepath=str(path), use_selection=False,
                          use_active_collection=False, bake_anim=True, bake_anim_use_all_actions=False, bake_anim_use_nla_strips=False,
                          bake_anim_step=1.0, bake_anim_simplify_factor=0.0, use_mesh_modifiers=False,
                          add_leaf_bones=False)
        finally:
            self._return_names()

    def _borrow_names(self):
        for original, copy in self.copies.items():
            pairs = [(original, copy)]
            if original.type == "MESH":
                pairs.append((original.data, copy.data))
            for own, stand_in in pairs:
                name = own.name
                self.renamed.append((own, name))
                own.name = f"{name[:40]}.facecap-export"
                stand_in.name = name

    def _return_names(self):
        for own, stand_in in [(o, c) for o, c in self.copies.items()]:
            stand_in.name = f"{stand_in.name[:40]}.facecap-copy"
            if own.type == "MESH":
                stand_in.data.name = f"{stand_in.data.name[:40]}.facecap-copy"
        for own, name in reversed(self.renamed):
            own.name = name
        self.renamed.clear()

    def __exit__(self, *exc):
        if self.renamed:
            self._return_names()
        # one by one, users first: bpy.data.batch_remove of a scene left Blender to crash on the next
        # read_factory_settings (5.0.1, measured); a copied mesh takes its shape keys with it
        kinds = ((bpy.types.Object, bpy.data.objects), (bpy.types.Mesh, bpy.data.meshes),
                 (bpy.types.Action, bpy.data.actions), (bpy.types.Scene, bpy.data.scenes))
        groups = [(collection, [i for i in self.made if isinstance(i, kind)]) for kind, collection in kinds]
        for collection, ids in groups:
            for id_data in ids:
                collection.remove(id_data)
        return False


def _fps_pair(fps):
    """(fps, fps_base) for Blender's render settings: whole rates exactly, NTSC-style ones as n / 1.001."""
    for base in (1.0, 1.001):
        n = round(fps * base)
        if 1 <= n <= 1000 and abs(n / base - fps) < 1e-6 * fps:
            return n, base
    return max(1, round(fps)), round(fps) / fps if fps > 0 else 1.0


def _call(operator, **options):
    """Call an exporter with the options this Blender's version has (4.2-5.0 differ in a few)."""
    known = set(operator.get_rna_type().properties.keys())
    result = operator(**{k: v for k, v in options.items() if k in known})
    if "FINISHED" not in result:
        raise FacecapError(f"Blender's {operator.idname_py()} exporter did not finish ({', '.join(result)})")
