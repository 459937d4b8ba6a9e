"""A reduced copy of a big armature that Blender evaluates instead of the whole rig.

Setting a control tags the whole armature: Blender evaluates every bone of it on every pose, 706 on
the Rigify human where a face uses about 200 (its deforming bones at the bound points, and what
they hang on: parents, constraint targets, the bones and properties their drivers read). The proxy
is a copy of the armature with only those bones, its constraints and drivers pointing at itself
instead of the original, and no custom shapes (drawing only). It lives in a scene of its own: each
update walks every node of the depsgraph it is in, and the user's holds far more than the rig (the
Rigify human's, with the original hidden, 12,000 operations: the metarig still points at the rig,
which brings its 706 bones and 220 widget objects back; the head-only rig's 5,900); the proxy's
own holds about 1,100. So a proxy pays even when it keeps most bones, if every control is on the
armature (``alone``: the user's scene is then not updated at all). ``evaluating`` gives the update to
call. It is checked against the original on a few poses when made, and is dropped if they differ.

Proxies and their scenes are tagged (``TAG``); ``remove_proxies`` deletes every one, before keying
or when a solve stops, so none reaches a saved file.
"""

import contextlib
import re

import bpy
import numpy as np

#: Custom property marking a proxy armature (its value: the original's name).
TAG = "facecap_rig_proxy"
#: Proxies are made (``rig-bench`` turns them off to time the whole armature in the same run).
USE = True
#: A proxy is made only when it leaves out at least this share of the armature's bones, or when it is
#: evaluated ``alone`` (its own scene then spares the update of the user's, whatever it leaves out).
WORTH = 0.3
#: Largest difference of a deforming bone's matrix (scene units) between the proxy and the original.
TOLERANCE = 1e-6
_BONE = re.compile(r'pose\.bones\["((?:[^"\\]|\\.)*)"\]|bones\["((?:[^"\\]|\\.)*)"\]')


def _bones_in(path):
    return {a or b for a, b in _BONE.findall(path or "")}


def _drivers(id_data):
    ad = getattr(id_data, "animation_data", None)
    return [] if ad is None else list(ad.drivers)


def needed_bones(armature, names):
    """``names`` and every bone of ``armature`` they depend on: parents, constraint targets and
    what the drivers of their channels and constraints read."""
    pose = armature.pose.bones
    reads = {}  # bone -> bones its drivers read
    for fc in _drivers(armature) + _drivers(armature.data):
        for bone in _bones_in(fc.data_path):
            for var in fc.driver.variables:
                for t in var.targets:
                    if t.id in (armature, armature.data):
                        reads.setdefault(bone, set()).update(_bones_in(t.data_path) | {t.bone_target} - {""})
    need, todo = set(), [n for n in names if n in pose]
    while todo:
        name = todo.pop()
        if name in need:
            continue
        need.add(name)
        pb = pose[name]
        more = set(reads.get(name, ()))
        if pb.parent is not None:
            more.add(pb.parent.name)
        for con in pb.constraints:
            for attr in ("subtarget", "pole_subtarget"):
                target = getattr(con, attr.replace("sub", ""), None)
                if target == armature and getattr(con, attr, ""):
                    more.add(getattr(con, attr))
            for t in getattr(con, "targets", ()):
                if t.target == armature and t.subtarget:
                    more.add(t.subtarget)
        todo += [n for n in more if n in pose and n not in need]
    return need


def _point_at(proxy, original):
    """Constraints and drivers of ``proxy`` that read ``original`` read the proxy instead."""
    for fc in _drivers(proxy) + _drivers(proxy.data):
        for var in fc.driver.variables:
            for t in var.targets:
                if t.id == original:
                    t.id = proxy
                elif t.id == original.data:
                    t.id = proxy.data
    for pb in proxy.pose.bones:
        for con in pb.constraints:
            for attr in ("target", "pole_target"):
                if getattr(con, attr, None) == original:
                    setattr(con, attr, proxy)
            for t in getattr(con, "targets", ()):
                if t.target == original:
                    t.target = proxy


def make_proxy(armature, names, *, alone=False):
    """A proxy of ``armature`` keeping ``names`` and what they need, in a scene of its own, or None
    when it would not pay (``alone``: it will be evaluated without the user's scene)."""
    need = needed_bones(armature, names)
    if not USE or (not alone and len(need) > (1.0 - WORTH) * len(armature.pose.bones)):
        return None
    proxy = armature.copy()
    proxy.data = armature.data.copy()
    proxy.name = proxy.data.name = f"{armature.name} (facecap proxy)"
    proxy[TAG] = proxy.data[TAG] = armature.name
    proxy.hide_viewport = False
    _point_at(proxy, armature)
    for id_data in (proxy, proxy.data):  # drivers of the bones left out would only fail
        for fc in _drivers(id_data):
            if _bones_in(fc.data_path) - need:
                id_data.animation_data.drivers.remove(fc)
    for pb in proxy.pose.bones:  # a widget object is a depsgraph node too; shapes only draw
        pb.custom_shape = None
    view_layer = bpy.context.view_layer
    bpy.context.scene.collection.objects.link(proxy)  # edit mode needs it in the context's view layer
    previous = view_layer.objects.active
    try:
        view_layer.objects.active = proxy
        bpy.ops.object.mode_set(mode="EDIT")
        edit = proxy.data.edit_bones
        for bone in [b for b in edit if b.name not in need]:
            edit.remove(bone)
        bpy.ops.object.mode_set(mode="OBJECT")
    finally:
        view_layer.objects.active = previous
        bpy.context.scene.collection.objects.unlink(proxy)
    scene = bpy.data.scenes.new(proxy.name)
    scene[TAG] = armature.name
    scene.collection.objects.link(proxy)
    return proxy


def _scene_of(proxy):
    return next(s for s in proxy.users_scene if TAG in s.keys())


@contextlib.contextmanager
def evaluating(proxy, original, *, alone=True):
    """The update that evaluates the proxy, for the block: its own scene's, at the current frame.
    Not ``alone`` (something the caller reads lives in the user's scene: controls on other IDs) the
    user's scene is updated too, the original out of its depsgraph meanwhile."""
    scene, own = bpy.context.scene, _scene_of(proxy)
    if (own.frame_current, own.frame_subframe) != (scene.frame_current, scene.frame_subframe):
        own.frame_current, own.frame_subframe = scene.frame_current, scene.frame_subframe
    update = own.view_layers[0].update
    if alone:
        yield update
        return
    main = bpy.context.view_layer.update

    def both():
        update()
        main()
    hidden = original.hide_viewport
    original.hide_viewport = True
    try:
        yield both
    finally:
        original.hide_viewport = hidden


def matches(proxy, original, controls, proxy_controls, bones, trials=3, seed=0):
    """Whether the proxy poses ``bones`` as the original does, at rest and at random control values."""
    rng = np.random.default_rng(seed)
    lo, hi = np.array([c.lower for c in controls]), np.array([c.upper for c in controls])
    saved = [c.get() for c in controls]
    try:
        for values in [np.array([c.rest for c in controls])] + [rng.uniform(lo, hi) for _ in range(trials)]:
            for c, v in zip(controls, values):
                c.set(float(v))
            bpy.context.view_layer.update()
            want = np.array([np.array(original.pose.bones[b].matrix) for b in bones])
            with evaluating(proxy, original) as update:
                for c, v in zip(proxy_controls, values):
                    c.set(float(v))
                update()
                got = np.array([np.array(proxy.pose.bones[b].matrix) for b in bones])
            if np.abs(got - want).max() > TOLERANCE:
                return False
        return True
    finally:
        for c, v in zip(controls, saved):
            c.set(v)
        bpy.context.view_layer.update()


def remove_proxies():
    """Delete every proxy armature (and its data and scene) facecap made."""
    for obj in [o for o in bpy.data.objects if TAG in o.keys()]:
        bpy.data.objects.remove(obj)
    for arm in [a for a in bpy.data.armatures if TAG in a.keys() and a.users == 0]:
        bpy.data.armatures.remove(arm)
    for scene in [s for s in bpy.data.scenes if TAG in s.keys()]:
        bpy.data.scenes.remove(scene)
