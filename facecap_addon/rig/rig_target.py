"""A rig's controls as the solve drives them: pose-bone channels, custom properties, shape keys.

A ``Control`` is one animatable value (an ID, a data path, an array index) with the rig's own
limits: a pose bone's Limit Location / Limit Rotation constraint, a custom property's UI range, a
shape key's slider range, else the span the user or the preset gives. Controls are named by the
user (``[rig] controls``) or by a preset:

* ``rigify_face``: the primary face controls of a Rigify rig (lips, lip corners, brows, lids,
  cheeks, nostrils, chin: their location; the jaw: its rotation);
* ``arkit_sliders``: every custom property of a control object named after an ARKit shape (the
  sliders of a control rig whose drivers move the face);
* ``shape_keys``: the mesh's own shape keys that no driver sets (corrective and combination keys
  driven by them are part of the rig, not controls).
"""

import math
import re
from dataclasses import dataclass

import bpy

from ...solvers.io.arkit import ARKIT_52
from ...solvers.errors import FacecapError

PRESETS = ("rigify_face", "arkit_sliders", "shape_keys")

#: Rigify face controls (bone names of a generated rig) and the channels solved on them.
RIGIFY_FACE_LOCATION = (
    "lips.L", "lips.R", "lip.T", "lip.B", "lip.T.L.001", "lip.T.R.001", "lip.B.L.001", "lip.B.R.001",
    "brow.T.L.001", "brow.T.L.002", "brow.T.L.003", "brow.T.R.001", "brow.T.R.002", "brow.T.R.003",
    "lid.T.L.002", "lid.B.L.002", "lid.T.R.002", "lid.B.R.002", "cheek.B.L.001", "cheek.B.R.001",
    "nose.L.001", "nose.R.001", "chin",
)
RIGIFY_FACE_ROTATION = ("jaw_master",)
#: Default span of a location channel without a Limit Location, in units of the bone's length.
LOCATION_SPAN = 1.0
#: Default span (radians) of a rotation channel without a Limit Rotation.
ROTATION_SPAN = math.radians(25.0)


@dataclass
class Control:
    """One solved value: ``owner`` (an ID) at ``path`` [``index``], within [lower, upper], rest ``rest``."""

    name: str
    owner: object
    path: str
    index: int
    lower: float
    upper: float
    rest: float = 0.0

    def _target(self):
        head, _, attr = self.path.rpartition(".")
        if self.path.startswith('["'):
            return None, self.path[2:-2]
        return (self.owner.path_resolve(head) if head else self.owner), attr

    def get(self):
        obj, attr = self._target()
        if obj is None:
            return float(self.owner[attr])
        value = getattr(obj, attr)
        return float(value[self.index] if self.index >= 0 else value)

    def set(self, value):
        obj, attr = self._target()
        if obj is None:
            self.owner[attr] = value
            self.owner.update_tag()  # a custom property set from Python does not tag its drivers' readers
            return
        if self.index < 0:
            setattr(obj, attr, value)
            return
        arr = getattr(obj, attr)
        arr[self.index] = value
        if attr == "rotation_quaternion" and self.index > 0:  # keep it a unit quaternion: w from the rest
            xyz = [arr[i] for i in (1, 2, 3)]
            arr[0] = math.sqrt(max(0.0, 1.0 - sum(v * v for v in xyz)))

    def setter(self):
        """``set`` with the data path resolved once (a pose is thousands of sets while probing)."""
        obj, attr = self._target()
        if obj is None or attr == "rotation_quaternion":
            return self.set
        if self.index < 0:
            return lambda value: setattr(obj, attr, value)
        arr, i = getattr(obj, attr), self.index

        def put(value):
            arr[i] = value
        return put

    @property
    def curve(self):
        """(data_path, index) of the F-curve keyed on ``owner``."""
        return self.path, max(self.index, 0)


def _quote(name):
    return name.replace("\\", "\\\\").replace('"', '\\"')


def bone_controls(armature, bone, channel, axes=(0, 1, 2), *, span=None):
    """Controls of ``bone``'s ``channel`` ("location" or "rotation") on the given axes, with the
    limits of its Limit Location / Limit Rotation constraint (local space) where it has one."""
    pb = armature.pose.bones.get(bone)
    if pb is None:
        raise FacecapError(f"rig target: armature '{armature.name}' has no bone '{bone}'")
    axis_names = "xyz"
    out = []
    if channel == "location":
        path, default = f'pose.bones["{_quote(bone)}"].location', span or LOCATION_SPAN * pb.bone.length
        limit = next((c for c in pb.constraints if c.type == "LIMIT_LOCATION" and c.owner_space == "LOCAL"
                      and not c.mute), None)
        for i in axes:
            lo, hi = -default, default
            if limit is not None:
                a = axis_names[i]
                lo = getattr(limit, f"min_{a}") if getattr(limit, f"use_min_{a}") else lo
                hi = getattr(limit, f"max_{a}") if getattr(limit, f"use_max_{a}") else hi
            out.append(Control(f"{bone}.loc_{axis_names[i]}", armature, path, i, lo, hi))
        return out
    if channel != "rotation":
        raise FacecapError(f"rig target: channel must be 'location' or 'rotation'; got '{channel}'")
    default = span or ROTATION_SPAN
    limit = next((c for c in pb.constraints if c.type == "LIMIT_ROTATION" and c.owner_space == "LOCAL"
                  and not c.mute), None)
    quaternion = pb.rotation_mode == "QUATERNION"
    for i in axes:
        lo, hi = -default, default
        if limit is not None:
            a = axis_names[i]
            lo = getattr(limit, f"min_{a}") if getattr(limit, f"use_limit_{a}") else lo
            hi = getattr(limit, f"max_{a}") if getattr(limit, f"use_limit_{a}") else hi
        if quaternion:  # the quaternion's vector part: sin(angle / 2) about the axis
            out.append(Control(f"{bone}.rot_{axis_names[i]}", armature, f'pose.bones["{_quote(bone)}"].rotation_quaternion',
                               i + 1, math.sin(lo / 2), math.sin(hi / 2)))
        elif pb.rotation_mode in ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"):
            out.append(Control(f"{bone}.rot_{axis_names[i]}", armature, f'pose.bones["{_quote(bone)}"].rotation_euler',
                               i, lo, hi))
        else:
            raise FacecapError(f"rig target: bone '{bone}' rotates in mode {pb.rotation_mode}; "
                               "facecap solves Euler or quaternion rotations")
    return out


def property_control(owner, prop, *, lower=None, upper=None, name=None):
    """A custom property of ``owner`` (that drivers read), with its UI range unless given."""
    if prop not in owner.keys():
        raise FacecapError(f"rig target: '{owner.name}' has no custom property '{prop}'")
    ui = owner.id_properties_ui(prop).as_dict()
    lo = ui.get("min", 0.0) if lower is None else lower
    hi = ui.get("max", 1.0) if upper is None else upper
    return Control(name or prop, owner, f'["{_quote(prop)}"]', -1, float(lo), float(hi), float(ui.get("default", 0.0)))


def driven_paths(id_data):
    """Data paths of ``id_data`` that a driver sets."""
    ad = id_data.animation_data
    return set() if ad is None else {d.data_path for d in ad.drivers}


def shape_key_controls(mesh):
    """The shape keys of ``mesh`` that no driver sets, as controls (slider ranges)."""
    key = mesh.data.shape_keys
    if key is None:
        raise FacecapError(f"rig target: '{mesh.name}' has no shape keys")
    driven = driven_paths(key)
    out = []
    for b in key.key_blocks:
        path = f'key_blocks["{_quote(b.name)}"].value'
        if b == key.reference_key or path in driven:
            continue
        out.append(Control(b.name, key, path, -1, b.slider_min, b.slider_max))
    return out


def preset_controls(preset, mesh, rig):
    """Controls of a preset (``PRESETS``); ``rig`` is the armature or control object it needs."""
    if preset == "shape_keys":
        return shape_key_controls(mesh)
    if rig is None:
        raise FacecapError(f"rig preset '{preset}' needs the rig object ([rig] object)")
    if preset == "rigify_face":
        if rig.type != "ARMATURE":
            raise FacecapError(f"rig preset 'rigify_face': '{rig.name}' is not an armature")
        found = [b for b in RIGIFY_FACE_LOCATION if b in rig.pose.bones]
        if len(found) < 8:
            raise FacecapError(f"rig preset 'rigify_face': '{rig.name}' has {len(found)} of the Rigify face "
                               "controls (lips.L, lip.T, brow.T.L.001...); is it a generated Rigify rig with a face?")
        out = [c for b in found for c in bone_controls(rig, b, "location")]
        for b in RIGIFY_FACE_ROTATION:
            if b in rig.pose.bones:
                out += bone_controls(rig, b, "rotation", axes=(0,))
        return out
    if preset == "arkit_sliders":
        props = [p for p in ARKIT_52 if p in rig.keys()]
        if not props:
            raise FacecapError(f"rig preset 'arkit_sliders': '{rig.name}' has no custom property named after an "
                               "ARKit shape (jawOpen, mouthSmileLeft...)")
        return [property_control(rig, p) for p in props]
    raise FacecapError(f"unknown rig preset '{preset}'; available: {', '.join(PRESETS)}")


_PATH = re.compile(r'^(pose\.bones\["(?P<bone>[^"]+)"\]\.(?P<channel>location|rotation)|\["(?P<prop>[^"]+)"\]'
                   r'|key_blocks\["(?P<key>[^"]+)"\]\.value)$')


def spec_controls(specs, mesh):
    """Controls named in ``[rig] controls``: tables {object, path, axes?, lower?, upper?, name?};
    ``path`` is 'pose.bones["bone"].location', 'pose.bones["bone"].rotation', '["property"]' or
    'key_blocks["shape"].value' (``object`` then names the mesh)."""
    out = []
    for i, spec in enumerate(specs):
        where = f"[rig] controls[{i}]"
        obj = bpy.data.objects.get(spec.get("object", ""))
        if obj is None:
            raise FacecapError(f"{where}: no object named '{spec.get('object', '')}'")
        m = _PATH.match(spec.get("path", ""))
        if m is None:
            raise FacecapError(f"{where}: path '{spec.get('path', '')}' is not a bone channel "
                               "(pose.bones[\"bone\"].location / .rotation), a custom property ([\"name\"]) "
                               "or a shape key (key_blocks[\"name\"].value)")
        lo, hi = spec.get("lower"), spec.get("upper")
        if m["bone"]:
            if obj.type != "ARMATURE":
                raise FacecapError(f"{where}: '{obj.name}' is not an armature")
            made = bone_controls(obj, m["bone"], m["channel"], tuple(spec.get("axes", (0, 1, 2))))
        elif m["prop"]:
            made = [property_control(obj, m["prop"], lower=lo, upper=hi, name=spec.get("name"))]
        else:
            key = obj.data.shape_keys if obj.type == "MESH" else None
            if key is None or m["key"] not in key.key_blocks:
                raise FacecapError(f"{where}: '{obj.name}' has no shape key '{m['key']}'")
            b = key.key_blocks[m["key"]]
            made = [Control(spec.get("name", b.name), key, m[0], -1, b.slider_min, b.slider_max)]
        for c in made:
            c.lower = c.lower if lo is None else float(lo)
            c.upper = c.upper if hi is None else float(hi)
            if not c.lower <= c.rest <= c.upper:
                raise FacecapError(f"{where}: the range [{c.lower:g}, {c.upper:g}] of '{c.name}' does not hold its "
                                   f"rest value {c.rest:g}")
        out += made
    return out


def driver_pairs(controls, ids):
    """Index pairs of controls read together by one driver of ``ids`` (its product and combination terms)."""
    by_ref = {}
    for i, c in enumerate(controls):
        by_ref[(c.owner.name, c.path.replace("'", '"'))] = i
    pairs = set()
    for id_data in ids:
        ad = getattr(id_data, "animation_data", None)
        if ad is None:
            continue
        for fc in ad.drivers:
            used = set()
            for var in fc.driver.variables:
                for t in var.targets:
                    if t.id is not None and t.data_path:
                        i = by_ref.get((t.id.name, t.data_path.replace("'", '"')))
                        if i is not None:
                            used.add(i)
            used = sorted(used)
            pairs |= {(a, b) for n, a in enumerate(used) for b in used[n + 1:]}
    return sorted(pairs)
