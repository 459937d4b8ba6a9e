"""Evaluate a rig at the bound points: set its controls, let Blender evaluate what it must, read back.

Blender computes only the rig itself: drivers (a slider's shape-key values, driven bone channels)
and the pose (bone matrices, constraints). The bound points are then computed in numpy from what
was read: the bound vertices' shape keys at the driven values, then linear-blend skinning by the
deforming bones of the mesh's Armature modifier. ``RigEvaluator`` checks that path against
Blender's own evaluated mesh on a few poses when it is built and evaluates the whole mesh instead
(slower, same result) if they differ, e.g. for a modifier it does not model.

Skinning is linear in the vertices, so the bound points are folded once per evaluator: for each
deforming bone b the sampled, weighted rest vertices K_b (and one K_b per shape key that a driver or
a control moves). A pose then costs O(markers x bones): points = sum_b R_b K_b + t_b k_b, where R_b,
t_b is the bone's skinning matrix. While evaluating, the mesh itself is hidden from the depsgraph so
Blender does not deform the whole mesh for nothing (numpy mode only; restored afterwards), and a
big armature is evaluated through a proxy holding only the bones the bound points depend on
(``rig_proxy``: the face of a whole Rigify human, not its 700 bones), in a scene of its own: when
every control is on the armature the user's scene is not updated at all while evaluating.
"""

import contextlib
import dataclasses

import numpy as np

from ...solvers.engine.threads import single_blas_thread
from ...solvers.errors import FacecapError
from ..scene.scene_data import vertex_group_bindings
from . import rig_proxy

#: Largest difference (metres) between the numpy path and Blender's evaluated mesh that is accepted.
CHECK_TOLERANCE = 1e-6


def _matrix(m):
    return np.array(m, dtype=np.float64)


class RigEvaluator:
    """Evaluates ``mesh``'s bound points (``marker_names``, vertex groups) for control values.

    ``controls`` are ``rig_target.Control`` objects (owner ID, setter, rest, limits). Call
    ``evaluate(values (N, C)) -> (N, M, 3)`` (mesh local space); the scene's controls are put back
    to what they were afterwards. ``reference``: the slow path, every bound vertex skinned per pose
    and the mesh evaluated by Blender too (what the fast path is checked against).
    """

    def __init__(self, mesh, controls, marker_names, *, binding=None, reference=False):
        import bpy  # Blender: this module is only used inside it

        self.bpy = bpy
        if mesh is None or mesh.type != "MESH":
            raise FacecapError(f"'{getattr(mesh, 'name', mesh)}' is not a mesh object")
        self.mesh, self.controls, self.reference = mesh, list(controls), reference
        bindings = binding if binding is not None else vertex_group_bindings(mesh, marker_names)
        self.marker_names = tuple(n for n in marker_names if n in bindings)
        if len(self.marker_names) < 3:
            raise FacecapError(f"rig target: only {len(self.marker_names)} of the take's markers are bound on "
                               f"'{mesh.name}' (vertex groups named after them)")
        self.vertices = np.unique(np.concatenate([bindings[n][0] for n in self.marker_names]))
        self._weights = None  # the vertex groups' weights at the bound vertices, read once (_group_weights)
        pos = {v: i for i, v in enumerate(self.vertices)}
        self.sample = np.zeros((len(self.marker_names), len(self.vertices)))
        for m, n in enumerate(self.marker_names):
            idx, w = bindings[n]
            for v, wt in zip(idx, w):
                self.sample[m, pos[v]] += wt
        self._read_shape_keys()
        self._read_skin()
        self.proxy, self.posed, self._controls = None, self.armature, self.controls
        self._setters = [c.set if reference else c.setter() for c in self.controls]
        self.folded = None if reference else self._fold()
        self.mode = "numpy"
        self.evaluations = 0
        self._driven = [self.blocks[k] for k in self._live_blocks(drivers_only=True)] if self.blocks else []
        self._driven_rest = np.array([b.value for b in self._driven])
        self._driven_moved = np.zeros(len(self._driven), dtype=bool)
        saved = self.current()
        try:
            self.neutral = self._points_blender(self.rest())
            if not self._numpy_matches(saved):
                self.mode = "mesh"
        finally:
            self.apply(saved)
            self.bpy.context.view_layer.update()
        self._use_proxy()

    def _use_proxy(self):
        """Evaluate the armature through a proxy of the bones the bound points need (numpy path; a
        small one only when every control is on it; not when the mesh's shape keys read the armature:
        the proxy would not drive them)."""
        if self.reference or self.mode != "numpy" or self.folded is None or self.armature is None or not self.bones:
            return
        arm = self.armature
        key_ad = self.key.animation_data if self.key is not None else None
        if key_ad is not None and any(t.id in (arm, arm.data) for fc in key_ad.drivers
                                      for v in fc.driver.variables for t in v.targets):
            return
        bones = list(self.bones) + [c.path.split('"')[1] for c in self.controls if c.owner == arm and '"' in c.path]
        try:
            proxy = rig_proxy.make_proxy(arm, bones, alone=all(c.owner == arm for c in self.controls))
        except RuntimeError:  # edit mode refused (another object held in a mode): the whole armature
            return
        if proxy is None:
            return
        controls = [dataclasses.replace(c, owner=proxy) if c.owner == arm else c for c in self.controls]
        if not rig_proxy.matches(proxy, arm, self.controls, controls, self.bones):
            rig_proxy.remove_proxies()
            return
        self.proxy, self.posed, self._controls = proxy, proxy, controls
        self._alone = all(c.owner == proxy for c in controls)  # nothing to update in the user's scene
        self._setters = [c.setter() for c in controls]
        self.bone_index = [proxy.pose.bones.find(b) for b in self.bones]
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
        """(V,) the weights of the vertex group ``vg`` at the bound vertices (0 where not in it)."""
        if self._weights is None:  # every group in one pass over the bound vertices' own groups: vg.weight() per
            # vertex and group raised for each vertex outside it (the Rigify face's probing 2.4 s -> 1.7 s)
            verts = self.mesh.data.vertices
            self._weights = np.zeros((len(self.vertices), len(self.mesh.vertex_groups)))
            for i, v in enumerate(self.vertices):
                for g in verts[int(v)].groups:
                    if g.group < self._weights.shape[1]:
                        self._weights[i, g.group] = g.weight
        return self._weights[:, vg.index].copy()

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
        return np.array([c.get() for c in self._controls], dtype=np.float64)

    def rest(self):
        return np.array([c.rest for c in self.controls], dtype=np.float64)

    def apply(self, values, previous=None):
        """Set the controls to ``values``; with ``previous`` (what they hold now) only those that change."""
        for i, (put, v) in enumerate(zip(self._setters, values)):
            if previous is None or v != previous[i]:
                put(float(v))

    # -- the folded skin: per-bone sums of the sampled vertices --------------------------------------
    def _live_blocks(self, drivers_only=False):
        """Indices of the shape keys whose value can change while evaluating: a control's or driven."""
        ad = self.key.animation_data if self.key is not None else None
        moved = {d.data_path for d in ad.drivers} if ad is not None else set()
        if drivers_only:
            moved -= {c.path for c in self.controls if c.owner == self.key}
        else:
            moved |= {c.path for c in self.controls if c.owner == self.key}
        return [k for k, b in enumerate(self.blocks) if b.path_from_id("value") in moved]

    def _fold(self):
        """The per-pose constants of ``_points_folded``; None when folding would not pay (too large)."""
        vals = np.array([b.value for b in self.blocks])
        live = self._live_blocks() if self.blocks else []
        still = np.setdiff1d(np.arange(len(self.blocks)), live)
        co = self.base
        if still.size:
            co = co + (vals[still] @ self.block_deltas[still].reshape(len(still), -1)).reshape(co.shape)
        M, B = len(self.marker_names), (len(self.bones) if self.armature is not None else 0)
        if (1 + len(live)) * M * max(B, 1) * 3 > 2e7:  # a huge rig with many driven keys: per vertex instead
            return None
        fold = {"live": np.asarray(live, dtype=np.intp), "still": still, "still_values": vals[still]}
        deltas = [self.block_deltas[k] for k in live]
        if B == 0:
            fold["rest"] = self.sample @ co
            fold["keys"] = np.array([self.sample @ d for d in deltas]).reshape(len(live), M, 3)
            return fold
        W = self.skin_normalised * self.skinned[:, None]  # (V, B)
        free = self.sample * (~self.skinned)[None]  # (M, V): the vertices no bone moves

        V = len(self.vertices)
        group = max(1, int(4e6 // (3 * V)))  # bones per product: a (V, group, 3) temporary at most

        def per_bone(c):  # sum_v sample[m, v] W[v, b] c[v, :] -> (M, B, 3)
            out = np.empty((M, B, 3))
            for a in range(0, B, group):
                part = W[:, a:a + group, None] * c[:, None, :]
                out[:, a:a + group] = (self.sample @ part.reshape(V, -1)).reshape(M, -1, 3)
            return out

        fold["weights"] = self.sample @ W  # (M, B): what the bones' translations carry
        fold["rest"], fold["free"] = per_bone(co), free @ co
        fold["keys"] = np.array([per_bone(d) for d in deltas]).reshape(len(live), M, B, 3)
        fold["keys_free"] = np.array([free @ d for d in deltas]).reshape(len(live), M, 3)
        return fold

    def _skin_matrices(self):
        """(B, 4, 4) the deforming bones' skinning matrices in the mesh's space."""
        n = len(self.posed.pose.bones)
        buf = np.empty(n * 16, dtype=np.float32)
        self.posed.pose.bones.foreach_get("matrix", buf)
        pose = buf.reshape(n, 4, 4).transpose(0, 2, 1).astype(np.float64)[self.bone_index]
        to_arm = np.linalg.inv(_matrix(self.armature.matrix_world)) @ _matrix(self.mesh.matrix_world)
        return np.linalg.inv(to_arm) @ (pose @ self.rest_inv) @ to_arm

    def _points_folded(self):
        fold = self.folded
        vals = np.array([b.value for b in self.blocks]) if self.blocks else np.zeros(0)
        if fold["still"].size and not np.array_equal(vals[fold["still"]], fold["still_values"]):
            return self._points_numpy()  # a key nothing was known to move has moved: the full path
        live = vals[fold["live"]] if fold["live"].size else np.zeros(0)
        on = np.flatnonzero(live)
        if "weights" not in fold:
            return fold["rest"] + np.tensordot(live[on], fold["keys"][on], axes=1)
        K, free = fold["rest"], fold["free"]
        if on.size:
            K = K + np.tensordot(live[on], fold["keys"][on], axes=1)
            free = free + np.tensordot(live[on], fold["keys_free"][on], axes=1)
        skin = self._skin_matrices()
        M, B = fold["weights"].shape
        rotated = K.reshape(M, B * 3) @ skin[:, :3, :3].transpose(0, 2, 1).reshape(B * 3, 3)
        return rotated + fold["weights"] @ skin[:, :3, 3] + free

    # -- evaluation --------------------------------------------------------------------------------
    def _points_numpy(self):
        co = self.base
        if self.blocks:
            vals = np.array([b.value for b in self.blocks])
            co = co + (vals @ self.block_deltas.reshape(len(vals), -1)).reshape(co.shape)
        if self.armature is not None and self.bones:
            skin = self._skin_matrices()
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

    def _points(self):
        return self._points_numpy() if self.folded is None else self._points_folded()

    def _numpy_matches(self, saved):
        if self.other_modifiers:
            return False
        rng = np.random.default_rng(0)
        lo = np.array([c.lower for c in self.controls])
        hi = np.array([c.upper for c in self.controls])
        trials = [self.rest()] + [rng.uniform(lo, hi) for _ in range(2)]
        exact = []
        for values in trials:
            exact.append(self._points_blender(values))
            if np.abs(self._points_numpy() - exact[-1]).max() > CHECK_TOLERANCE:
                return False
        # the fast path as it runs (folded skin, mesh hidden), on the same poses
        if self.folded is not None:
            fast = self.evaluate(np.array(trials[::-1]))[::-1]
            self.evaluations -= len(trials)
            if np.abs(fast - np.array(exact)).max() > CHECK_TOLERANCE:
                self.folded = None  # the per-vertex path, checked above
        return True

    def _hide_mesh(self):
        """Keep Blender from deforming the whole mesh on every pose (fast numpy path only: the
        points are computed here; a driven shape key needs its mesh evaluated, so then not).
        Returns the setting to put back, or None."""
        if self.reference or self.folded is None or self.folded["live"].size or self.mesh.hide_viewport:
            return None
        if self.proxy is not None and self._alone:  # the user's scene is not updated: nothing to hide
            return None
        self.mesh.hide_viewport = True
        return False

    def evaluate(self, values, progress=None):
        """Bound points (N, M, 3) of the rig at control values (N, C); ``progress(done, total)``."""
        values = np.atleast_2d(np.asarray(values, dtype=np.float64))
        saved = self.current()
        out = np.empty((len(values), len(self.marker_names), 3))
        update = self.bpy.context.view_layer.update
        held = saved
        hidden = self._hide_mesh() if self.mode == "numpy" else None
        try:
            with contextlib.ExitStack() as stack:
                if self.proxy is not None:  # the proxy's own scene (and the user's, not alone)
                    update = stack.enter_context(rig_proxy.evaluating(self.proxy, self.armature,
                                                                      alone=self._alone))
                stack.callback(self.apply, saved)
                stack.enter_context(single_blas_thread())  # tiny products per pose: BLAS threads only contend
                for i, row in enumerate(values):
                    if self.mode == "numpy":
                        self.apply(row, held)
                        held = row
                        update()
                        out[i] = self._points()
                    else:
                        out[i] = self._points_blender(row)
                    if self._driven:
                        now = np.array([b.value for b in self._driven])
                        self._driven_moved |= np.abs(now - self._driven_rest) > 1e-6
                    if progress is not None and i % 64 == 63 and progress(i + 1, len(values)) is False:
                        raise FacecapError("rig evaluation cancelled")
        finally:
            if hidden is not None:
                self.mesh.hide_viewport = hidden
            update()
        self.evaluations += len(values)
        return out

    def close(self):
        """Remove the proxy armature (``rig_proxy``): evaluations after it use the whole armature."""
        if self.proxy is not None:
            self.proxy = None
            self.posed, self._controls = self.armature, self.controls
            self._setters = [c.setter() for c in self.controls]
            self.bone_index = [self.armature.pose.bones.find(b) for b in self.bones]
            rig_proxy.remove_proxies()

    def still_driven(self):
        """Names of the driven shape keys that no evaluation so far has moved from their rest value:
        their drivers read nothing the controls move (or could not run)."""
        return [b.name for b, moved in zip(self._driven, self._driven_moved) if not moved]

    def deltas(self, offsets):
        """Displacement of the bound points (N, M, 3) from the rest pose for control offsets from rest."""
        return self.evaluate(np.atleast_2d(offsets) + self.rest()) - self.neutral
