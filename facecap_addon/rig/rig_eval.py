"""Evaluate a rig at the bound points: set its controls, let Blender evaluate what it must, read back.

Blender computes only the rig itself: drivers (a slider's shape-key values, driven bone channels)
and the pose (bone matrices, constraints). The bound points are then computed in numpy from what
was read: the bound vertices' shape keys at the driven values, then linear-blend skinning by the
deforming bones of the mesh's Armature modifier. ``RigEvaluator`` checks that path against
Blender's own evaluated mesh on a few poses when it is built and evaluates the whole mesh instead
(slower, same result) if they differ, e.g. for a modifier it does not model.
"""

import numpy as np

from ...solvers.engine.threads import single_blas_thread
from ...solvers.errors import FacecapError
from ..scene.scene_data import vertex_group_bindings

#: Largest difference (metres) between the numpy path and Blender's evaluated mesh that is accepted.
CHECK_TOLERANCE = 1e-6


def _matrix(m):
    return np.array(m, dtype=np.float64)


class RigEvaluator:
    """Evaluates ``mesh``'s bound points (``marker_names``, vertex groups) for control values.

    ``controls`` are ``rig_target.Control`` objects (owner ID, setter, rest, limits). Call
    ``evaluate(values (N, C)) -> (N, M, 3)`` (mesh local space); the scene's controls are put back
    to what they were afterwards.
    """

    def __init__(self, mesh, controls, marker_names, *, binding=None):
        import bpy  # Blender: this module is only used inside it

        self.bpy = bpy
        if mesh is None or mesh.type != "MESH":
            raise FacecapError(f"'{getattr(mesh, 'name', mesh)}' is not a mesh object")
        self.mesh, self.controls = mesh, list(controls)
        bindings = binding if binding is not None else vertex_group_bindings(mesh, marker_names)
        self.marker_names = tuple(n for n in marker_names if n in bindings)
        if len(self.marker_names) < 3:
            raise FacecapError(f"rig target: only {len(self.marker_names)} of the take's markers are bound on "
                               f"'{mesh.name}' (vertex groups named after them)")
        self.vertices = np.unique(np.concatenate([bindings[n][0] for n in self.marker_names]))
        pos = {v: i for i, v in enumerate(self.vertices)}
        self.sample = np.zeros((len(self.marker_names), len(self.vertices)))
        for m, n in enumerate(self.marker_names):
            idx, w = bindings[n]
            for v, wt in zip(idx, w):
                self.sample[m, pos[v]] += wt
        self._read_shape_keys()
        self._read_skin()
        self.mode = "numpy"
        self.evaluations = 0
        saved = self.current()
        try:
            self.neutral = self._points_blender(self.rest())
            if not self._numpy_matches(saved):
                self.mode = "mesh"
        finally:
            self.apply(saved)
            self.bpy.context.view_layer.update()

    # -- reading the mesh once ---------------------------------------------------------------------
    def _read_shape_keys(self):
        me, V = self.mesh.data, self.vertices
        n = len(me.vertices)
        co = np.empty(n * 3)
        me.vertices.foreach_get("co", co)
        self.base = co.reshape(n, 3)[V]
        self.key = me.shape_keys
        self.blocks, self.block_deltas = [], []
        if self.key is None:
            return
        ref = self.key.reference_key
        cache = {}

        def at(block):
            if block.name not in cache:
                buf = np.empty(n * 3)
                block.data.foreach_get("co", buf)
                cache[block.name] = buf.reshape(n, 3)[V]
            return cache[block.name]

        self.base = at(ref)
        for block in self.key.key_blocks:
            if block == ref or block.mute:
                continue
            rel = block.relative_key if block.relative_key is not None else ref
            d = at(block) - at(rel)
            if block.vertex_group:
                vg = self.mesh.vertex_groups.get(block.vertex_group)
                d = d * self._group_weights(vg)[:, None] if vg is not None else d
            self.blocks.append(block)
            self.block_deltas.append(d)
        self.block_deltas = np.array(self.block_deltas).reshape(len(self.blocks), len(V), 3)

    def _group_weights(self, vg):
        out = np.zeros(len(self.vertices))
        for i, v in enumerate(self.vertices):
            try:
                out[i] = vg.weight(int(v))
            except RuntimeError:  # not in the group
                out[i] = 0.0
        return out

    def _read_skin(self):
        self.armature, self.bones = None, []
        mods = [m for m in self.mesh.modifiers if m.show_viewport]
        arm_mods = [m for m in mods if m.type == "ARMATURE" and m.object is not None]
        self.other_modifiers = [m.name for m in mods if m.type != "ARMATURE"]
        if not arm_mods:
            return
        if len(arm_mods) > 1:
            self.other_modifiers.append(arm_mods[1].name)
        mod = arm_mods[0]
        self.armature = mod.object
        deform = {b.name for b in self.armature.data.bones if b.use_deform}
        groups = [vg for vg in self.mesh.vertex_groups if vg.name in deform] if mod.use_vertex_groups else []
        self.bones = [vg.name for vg in groups]
        W = np.zeros((len(self.vertices), len(groups)))
        for j, vg in enumerate(groups):
            W[:, j] = self._group_weights(vg)
        keep = W.any(axis=0)
        self.bones = [b for b, k in zip(self.bones, keep) if k]
        self.skin = W[:, keep]
        self.bone_index = [self.armature.pose.bones.find(b) for b in self.bones]
        self.rest_inv = np.array([np.linalg.inv(_matrix(self.armature.data.bones[b].matrix_local)) for b in self.bones])
        total = self.skin.sum(axis=1)  # the Armature modifier divides by the total weight where it is > 0
        self.skinned = total > 1e-4
        self.skin_normalised = self.skin / np.where(self.skinned, total, 1.0)[:, None]

    # -- controls ----------------------------------------------------------------------------------
    def current(self):
        return np.array([c.get() for c in self.controls], dtype=np.float64)

    def rest(self):
        return np.array([c.rest for c in self.controls], dtype=np.float64)

    def apply(self, values, previous=None):
        """Set the controls to ``values``; with ``previous`` (what they hold now) only those that change."""
        for i, (c, v) in enumerate(zip(self.controls, values)):
            if previous is None or v != previous[i]:
                c.set(float(v))

    # -- evaluation --------------------------------------------------------------------------------
    def _points_numpy(self):
        co = self.base
        if self.blocks:
            vals = np.array([b.value for b in self.blocks])
            co = co + (vals @ self.block_deltas.reshape(len(vals), -1)).reshape(co.shape)
        if self.armature is not None and self.bones:
            n = len(self.armature.pose.bones)
            buf = np.empty(n * 16, dtype=np.float32)
            self.armature.pose.bones.foreach_get("matrix", buf)
            pose = buf.reshape(n, 4, 4).transpose(0, 2, 1).astype(np.float64)[self.bone_index]
            to_arm = np.linalg.inv(_matrix(self.armature.matrix_world)) @ _matrix(self.mesh.matrix_world)
            skin = np.linalg.inv(to_arm) @ (pose @ self.rest_inv) @ to_arm  # (B, 4, 4), mesh space
            per_vertex = (self.skin_normalised @ skin.reshape(len(skin), 16)).reshape(-1, 4, 4)
            moved = (per_vertex[:, :3, :3] @ co[:, :, None])[:, :, 0] + per_vertex[:, :3, 3]
            co = np.where(self.skinned[:, None], moved, co)
        return self.sample @ co

    def _points_blender(self, values):
        self.apply(values)
        self.bpy.context.view_layer.update()
        dg = self.bpy.context.evaluated_depsgraph_get()
        ev = self.mesh.evaluated_get(dg)
        me = ev.to_mesh()
        try:
            n = len(me.vertices)
            if n != len(self.mesh.data.vertices):
                raise FacecapError(f"rig target: the modifiers of '{self.mesh.name}' change its vertex count; "
                                   "facecap needs the bound vertices to keep their indices")
            co = np.empty(n * 3)
            me.vertices.foreach_get("co", co)
        finally:
            ev.to_mesh_clear()
        return self.sample @ co.reshape(n, 3)[self.vertices]

    def _numpy_matches(self, saved):
        if self.other_modifiers:
            return False
        rng = np.random.default_rng(0)
        lo = np.array([c.lower for c in self.controls])
        hi = np.array([c.upper for c in self.controls])
        for trial in range(3):
            values = self.rest() if trial == 0 else rng.uniform(lo, hi)
            exact = self._points_blender(values)
            if np.abs(self._points_numpy() - exact).max() > CHECK_TOLERANCE:
                return False
        return True

    def evaluate(self, values, progress=None):
        """Bound points (N, M, 3) of the rig at control values (N, C); ``progress(done, total)``."""
        values = np.atleast_2d(np.asarray(values, dtype=np.float64))
        saved = self.current()
        out = np.empty((len(values), len(self.marker_names), 3))
        update = self.bpy.context.view_layer.update
        held = saved
        try:
            with single_blas_thread():  # tiny products per pose: BLAS threads only contend
                for i, row in enumerate(values):
                    if self.mode == "numpy":
                        self.apply(row, held)
                        held = row
                        update()
                        out[i] = self._points_numpy()
                    else:
                        out[i] = self._points_blender(row)
                    if progress is not None and i % 64 == 63 and progress(i + 1, len(values)) is False:
                        raise FacecapError("rig evaluation cancelled")
        finally:
            self.apply(saved)
            update()
        self.evaluations += len(values)
        return out

    def deltas(self, offsets):
        """Displacement of the bound points (N, M, 3) from the rest pose for control offsets from rest."""
        return self.evaluate(np.atleast_2d(offsets) + self.rest()) - self.neutral
