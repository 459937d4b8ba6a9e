"""A control rig mixing units, as users build them: 22 controls on the sample character.

* 15 custom-property sliders on the empty ``FaceSliders`` (0..1, and ``jawSide`` from -1 to 1);
* 7 channels of 6 control bones of the armature ``FaceJoysticks`` (they deform nothing): a 2D mouth
  joystick (X and Z), a jaw joystick and two brow joysticks moving +-1 cm (Limit Location), two lid
  bones rotating +-0.4 rad about X (Limit Rotation).

They drive 39 of the face's ARKit shape keys through smoothstep, pow, sin and clamp curves (one
side of a joystick per key, ``browInnerUp`` from both brows), plus a corrective on the product of
the jaw opening and the smile and an in-between half way through the jaw's opening. Every driver is
a simple expression (Blender evaluates it without Python). ``read_back`` turns solved shape-key
weights into control values through the same curves: the plain-keys baseline of the tests and
``rig-bench``.
"""

import bpy
import numpy as np

from .rig_samples import add_driver, add_key, mesh_coords

ARMATURE = "FaceJoysticks"
SLIDERS = "FaceSliders"
#: Joystick travel (metres) and lid rotation (radians) each side of rest.
TRAVEL, TURN = 0.01, 0.4
#: (bone, channel, axes): the bone controls, in order.
BONES = (("mouth", "location", (0, 2)), ("jaw", "location", (2,)), ("brow.L", "location", (2,)),
         ("brow.R", "location", (2,)), ("lid.L", "rotation", (0,)), ("lid.R", "rotation", (0,)))
#: (slider, lower, upper)
SLIDER_RANGES = (("jawSide", -1.0, 1.0),) + tuple((n, 0.0, 1.0) for n in (
    "cheekPuff", "mouthFunnel", "mouthPucker", "mouthRollLower", "mouthRollUpper", "mouthShrug", "mouthPress",
    "mouthStretchLeft", "mouthStretchRight", "noseSneer", "cheekSquintLeft", "cheekSquintRight", "mouthUpperUp",
    "mouthLowerDown"))
#: Response curves of a normalised input t in [0, 1]: (driver expression of ``t``, numpy function).
CURVES = {
    "smoothstep": ("smoothstep(0, 1, {t})", lambda t: t * t * (3 - 2 * t)),
    "pow": ("pow({t}, 1.5)", lambda t: t ** 1.5),
    "sin": ("sin({t}*pi/2)", lambda t: np.sin(t * np.pi / 2)),
    "clamp": ("clamp(1.25*{t})", lambda t: np.clip(1.25 * t, 0.0, 1.0)),
}
#: shape key -> (control, side, curve): the key follows ``curve(clamp(side * control / reach))``.
KEYS = {
    "mouthLeft": ("mouth.loc_x", 1, "sin"), "mouthRight": ("mouth.loc_x", -1, "sin"),
    "mouthSmileLeft": ("mouth.loc_z", 1, "smoothstep"), "mouthSmileRight": ("mouth.loc_z", 1, "smoothstep"),
    "mouthFrownLeft": ("mouth.loc_z", -1, "pow"), "mouthFrownRight": ("mouth.loc_z", -1, "pow"),
    "jawOpen": ("jaw.loc_z", -1, "smoothstep"), "mouthClose": ("jaw.loc_z", 1, "clamp"),
    "jawForward": ("jaw.loc_z", 1, "sin"),
    "browOuterUpLeft": ("brow.L.loc_z", 1, "sin"), "browDownLeft": ("brow.L.loc_z", -1, "pow"),
    "browOuterUpRight": ("brow.R.loc_z", 1, "sin"), "browDownRight": ("brow.R.loc_z", -1, "pow"),
    "eyeBlinkLeft": ("lid.L.rot_x", 1, "smoothstep"), "eyeWideLeft": ("lid.L.rot_x", -1, "clamp"),
    "eyeBlinkRight": ("lid.R.rot_x", 1, "smoothstep"), "eyeWideRight": ("lid.R.rot_x", -1, "clamp"),
    "jawLeft": ("jawSide", -1, "sin"), "jawRight": ("jawSide", 1, "sin"),
    "cheekPuff": ("cheekPuff", 1, "pow"), "mouthFunnel": ("mouthFunnel", 1, "smoothstep"),
    "mouthPucker": ("mouthPucker", 1, "sin"), "mouthRollLower": ("mouthRollLower", 1, "clamp"),
    "mouthRollUpper": ("mouthRollUpper", 1, "pow"),
    "mouthShrugLower": ("mouthShrug", 1, "smoothstep"), "mouthShrugUpper": ("mouthShrug", 1, "sin"),
    "mouthPressLeft": ("mouthPress", 1, "clamp"), "mouthPressRight": ("mouthPress", 1, "clamp"),
    "mouthStretchLeft": ("mouthStretchLeft", 1, "sin"), "mouthStretchRight": ("mouthStretchRight", 1, "sin"),
    "noseSneerLeft": ("noseSneer", 1, "pow"), "noseSneerRight": ("noseSneer", 1, "pow"),
    "cheekSquintLeft": ("cheekSquintLeft", 1, "sin"), "cheekSquintRight": ("cheekSquintRight", 1, "sin"),
    "mouthUpperUpLeft": ("mouthUpperUp", 1, "smoothstep"), "mouthUpperUpRight": ("mouthUpperUp", 1, "smoothstep"),
    "mouthLowerDownLeft": ("mouthLowerDown", 1, "sin"), "mouthLowerDownRight": ("mouthLowerDown", 1, "sin"),
}
#: browInnerUp rises with either brow: the mean of the two brows' sin curves.
INNER_BROW = "browInnerUp"
#: The corrective fires on (jaw opening) x (smile); the in-between peaks half way through the opening.
CORRECTIVE = ("fix_jawOpen_mouthSmile", ("jaw.loc_z", -1), ("mouth.loc_z", 1), -0.6)
INBETWEEN = ("jawOpen_mid", ("jaw.loc_z", -1), 0.35)


def _reach(control):
    return TURN if control.endswith("rot_x") else TRAVEL if "." in control else 1.0


def _source(control, rig, sliders):
    """(ID, data path) a driver variable reads for ``control``."""
    if "." not in control:
        return sliders, f'["{control}"]'
    bone, channel = control.rsplit(".", 1)
    axis = "xyz".index(channel[-1])
    prop = "rotation_euler" if channel.startswith("rot") else "location"
    return rig, f'pose.bones["{bone}"].{prop}[{axis}]'


def _t(side, control, var="v"):
    """A driver sub-expression: the control's normalised travel to one side, clamped to [0, 1]."""
    return f"clamp({'-' if side < 0 else ''}{var}/{_reach(control):g})"


def controls_spec():
    """``[rig] controls`` of the mixed rig, bones first."""
    specs = [{"object": ARMATURE, "path": f'pose.bones["{b}"].{channel}', "axes": list(axes)}
             for b, channel, axes in BONES]
    return specs + [{"object": SLIDERS, "path": f'["{n}"]'} for n, _, _ in SLIDER_RANGES]


def control_names():
    return [f"{b}.{'loc' if ch == 'location' else 'rot'}_{'xyz'[a]}" for b, ch, axes in BONES for a in axes] \
        + [n for n, _, _ in SLIDER_RANGES]


def rig_section():
    """The take config's ``[rig]`` for the mixed rig."""
    items = []
    for s in controls_spec():
        axes = f", axes = {s['axes']}" if "axes" in s else ""
        items.append("{object = \"%s\", path = '%s'%s}" % (s["object"], s["path"], axes))
    return "[rig]\ncontrols = [" + ", ".join(items) + "]\n"


def _armature(mesh):
    arm = bpy.data.objects.new(ARMATURE, bpy.data.armatures.new(ARMATURE))
    for coll in mesh.users_collection:
        coll.objects.link(arm)
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    for i, (name, _, _) in enumerate(BONES):
        b = arm.data.edit_bones.new(name)
        b.head, b.tail = (0.25 + 0.03 * i, 0.0, 0.0), (0.25 + 0.03 * i, 0.0, 0.02)
        b.use_deform = False
    bpy.ops.object.mode_set(mode="OBJECT")
    for name, channel, axes in BONES:
        pb = arm.pose.bones[name]
        pb.rotation_mode = "XYZ"
        con = pb.constraints.new("LIMIT_LOCATION" if channel == "location" else "LIMIT_ROTATION")
        con.owner_space = "LOCAL"
        for a in "xyz":
            if channel == "location":
                for end in ("min", "max"):
                    setattr(con, f"use_{end}_{a}", True)
                reach = TRAVEL if "xyz".index(a) in axes else 0.0
                setattr(con, f"min_{a}", -reach)
                setattr(con, f"max_{a}", reach)
            else:
                setattr(con, f"use_limit_{a}", True)
                reach = TURN if "xyz".index(a) in axes else 0.0
                setattr(con, f"min_{a}", -reach)
                setattr(con, f"max_{a}", reach)
    return arm


def build_mixed_rig(mesh):
    """(armature, sliders object) driving ``mesh``'s shape keys (see the module docstring)."""
    key = mesh.data.shape_keys
    rig = _armature(mesh)
    sliders = bpy.data.objects.new(SLIDERS, None)
    for coll in mesh.users_collection:
        coll.objects.link(sliders)
    for name, lo, hi in SLIDER_RANGES:
        sliders[name] = 0.0
        sliders.id_properties_ui(name).update(min=lo, max=hi, soft_min=lo, soft_max=hi, default=0.0)
    for shape, (control, side, curve) in KEYS.items():
        expression = CURVES[curve][0].format(t=_t(side, control))
        add_driver(key, f'key_blocks["{shape}"].value', expression, {"v": _source(control, rig, sliders)})
    brows = {"l": _source("brow.L.loc_z", rig, sliders), "r": _source("brow.R.loc_z", rig, sliders)}
    add_driver(key, f'key_blocks["{INNER_BROW}"].value',
            f"0.5*(sin({_t(1, 'brow.L.loc_z', 'l')}*pi/2) + sin({_t(1, 'brow.R.loc_z', 'r')}*pi/2))", brows)
    _add_fixes(mesh, rig, sliders)
    return rig, sliders


def _add_fixes(mesh, rig, sliders):
    key = mesh.data.shape_keys
    base = mesh_coords(mesh.data, key.reference_key)

    def delta(name):
        return mesh_coords(mesh.data, key.key_blocks[name]) - base

    name, (a, sa), (b, sb), strength = CORRECTIVE
    d = strength * 0.5 * (delta("jawOpen") + 0.5 * (delta("mouthSmileLeft") + delta("mouthSmileRight")))
    d[:, 0] += 0.3 * np.abs(d).sum(axis=1) * np.sign(np.mean(d[:, 0]) or 1.0)
    add_key(mesh, name, base + d)
    add_driver(key, f'key_blocks["{name}"].value', f"{_t(sa, a, 'a')}*{_t(sb, b, 'b')}",
            {"a": _source(a, rig, sliders), "b": _source(b, rig, sliders)})
    name, (c, side), strength = INBETWEEN
    push = np.zeros_like(base)
    push[:, 1] = -strength * np.linalg.norm(delta("jawOpen"), axis=1)
    add_key(mesh, name, base + push)
    add_driver(key, f'key_blocks["{name}"].value', f"max(0, 1 - abs(2*{_t(side, c)} - 1))", {"v": _source(c, rig, sliders)})


def _key_curve(shape, values):
    control, side, curve = KEYS[shape]
    return CURVES[curve][1](np.clip(side * np.asarray(values) / _reach(control), 0.0, 1.0))


def with_corrective_events(names, values, *, every=150, rest=60, seed=0):
    """``values`` (F, C) with the jaw opening while the mouth smiles every ``every`` frames (a
    smooth bump, 40-70 % of each side's travel), so that the corrective fires; clipped to the travel."""
    rng = np.random.default_rng(seed)
    out = np.array(values, dtype=np.float64)
    t = np.arange(len(out))
    (_, (a, sa), (b, sb), _) = CORRECTIVE
    for centre in range(rest + every // 2, len(out) - rest - 20, every):
        bump = np.exp(-0.5 * ((t - centre) / rng.uniform(6, 12)) ** 2)
        out[:, names.index(a)] += sa * rng.uniform(0.4, 0.7) * _reach(a) * bump
        out[:, names.index(b)] += sb * rng.uniform(0.4, 0.7) * _reach(b) * bump
    return out


def truth_limits(values, names, share=0.75):
    """``values`` (F, C) clipped to ``share`` of each control's reach: a clamp curve saturates at 0.8 of
    it, where no marker can tell the control's value."""
    reach = np.array([_reach(n) for n in names])
    return np.clip(values, -share * reach, share * reach)


def firing(names, values, threshold=0.05):
    """(F,) bool: the frames where the corrective fires above ``threshold`` for control values (F, C)."""
    _, (a, sa), (b, sb), _ = CORRECTIVE
    ta = np.clip(sa * values[:, names.index(a)] / _reach(a), 0, 1)
    tb = np.clip(sb * values[:, names.index(b)] / _reach(b), 0, 1)
    return ta * tb > threshold


def read_back(shape_names, weights, limits, *, grid=4001):
    """Control values (F, C) from solved shape-key weights (F, K), through the drivers: for each
    control, the value in its ``limits`` {control: (lower, upper)} whose driven keys come closest
    (least squares over its keys) to the solved weights. Controls in the order of ``control_names``."""
    names = control_names()
    out = np.zeros((weights.shape[0], len(names)))
    cols = {n: i for i, n in enumerate(shape_names)}
    for c, control in enumerate(names):
        lo, hi = limits[control]
        candidates = np.linspace(lo, hi, grid)
        keys = [k for k, (ctrl, _, _) in KEYS.items() if ctrl == control and k in cols]
        if control.startswith("brow.") and INNER_BROW in cols:
            keys.append(INNER_BROW)
        cost = np.zeros((weights.shape[0], grid))
        for k in keys:
            if k == INNER_BROW:  # the other brow's half taken as solved (read back after it below)
                curve = 0.5 * CURVES["sin"][1](np.clip(candidates / TRAVEL, 0, 1))
                cost += (0.5 * weights[:, [cols[k]]] - curve[None]) ** 2
                continue
            cost += (np.nan_to_num(weights[:, [cols[k]]]) - _key_curve(k, candidates)[None]) ** 2
        out[:, c] = candidates[np.argmin(cost, axis=1)]
        out[~np.isfinite(weights).all(axis=1), c] = np.nan
    return out
