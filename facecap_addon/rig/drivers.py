"""Drivers in what facecap solves: the shape keys a driver sets, what it reads, and the drivers that
Blender cannot run.

A shape key whose value a driver sets cannot be keyed: at playback the driver overrides the keys.
So the shape-key solve leaves such keys out (``driven_keys``) and says so in one line; where every
driver of them reads only the mesh's own undriven keys (correctives on products of shapes, in-betweens),
the keys can be solved *through* their drivers instead, as the rig preset ``shape_keys`` does
(``solved_through_drivers``). A scripted driver whose expression needs Python that Blender does not
run (auto-run is off in a file it does not trust; facecap never turns it on), or that is broken,
leaves its value as it was: ``unrunnable`` finds them after an update, ``unrunnable_note`` names them
once with how to trust the file.
"""

import re
from dataclasses import dataclass

#: A driver target reading a shape key's value on a Key datablock.
_KEY_VALUE = re.compile(r'^key_blocks\[["\'](?P<name>.+)["\']\]\.value$')
#: How to let Blender run a trusted file's Python (facecap never does it for the user).
TRUST = ("if you trust its author, let Blender run its scripts: Preferences > Save & Load > Auto Run Python Scripts "
         "(or a trusted path there) and solve it in the sidebar, or run facecap inside Blender started with "
         "--enable-autoexec (blender -b -y -P <extension>/facecap_addon/cli.py -- ...); facecap's own command line "
         "never runs a .blend's scripts. Otherwise fix or remove the drivers")


@dataclass(frozen=True)
class KeyDriver:
    """The driver of one shape key: its expression, what it reads ((ID name, data path) per
    variable target) and, of those, the names of the mesh's own shape keys."""

    key: str
    expression: str
    reads: tuple
    own_keys: tuple


def driven_keys(mesh):
    """{shape key name: KeyDriver} of ``mesh``'s shape keys whose value a driver sets."""
    key = getattr(mesh.data, "shape_keys", None)
    ad = getattr(key, "animation_data", None)
    if ad is None:
        return {}
    out = {}
    for fc in ad.drivers:
        m = _KEY_VALUE.match(fc.data_path)
        if m is None or m["name"] not in key.key_blocks:
            continue
        reads, own = [], []
        for var in fc.driver.variables:
            for t in var.targets:
                if t.id is None:
                    continue
                reads.append((t.id.name, t.data_path))
                k = _KEY_VALUE.match(t.data_path or "")
                if t.id == key and k is not None:
                    own.append(k["name"])
        out[m["name"]] = KeyDriver(m["name"], fc.driver.expression if fc.driver.type == "SCRIPTED" else fc.driver.type,
                                   tuple(reads), tuple(own))
    return out


def solved_through_drivers(mesh):
    """Whether every driven key of ``mesh`` reads only the mesh's own undriven keys (and reads some):
    then the ``shape_keys`` rig preset solves the undriven keys with the driven ones firing through
    their drivers."""
    drivers = driven_keys(mesh)
    if not drivers:
        return False
    return all(d.own_keys and len(d.own_keys) == len(d.reads) and not set(d.own_keys) & drivers.keys()
               for d in drivers.values())


def left_out_note(mesh, drivers=None):
    """The one line saying which of ``mesh``'s keys are left out of a shape-key solve (their drivers
    set them), or None."""
    drivers = driven_keys(mesh) if drivers is None else drivers
    if not drivers:
        return None
    names = sorted(drivers)
    readers = sorted({n for d in drivers.values() for n, _ in d.reads} - {mesh.data.shape_keys.name})
    by = f" (reading {', '.join(readers[:4])}{'...' if len(readers) > 4 else ''})" if readers else ""
    how = ("the rig target Shape Keys + Correctives ([rig] preset = \"shape_keys\") solves them through their "
           "drivers" if solved_through_drivers(mesh) else "a rig target naming the controls the drivers read "
           "([rig] controls; Solve > Target) solves them through their drivers")
    return (f"{len(names)} shape key(s) of '{mesh.name}' are set by drivers{by}, which would override any key: left "
            f"out of the solve: {', '.join(names[:8])}{'...' if len(names) > 8 else ''}; {how}")


def _drivers_of(id_data):
    ad = getattr(id_data, "animation_data", None)
    return [] if ad is None else list(ad.drivers)


def rig_ids(mesh, controls):
    """The IDs whose drivers move ``mesh``'s points: the mesh, its data and shape keys, its armatures (object and
    data), and the IDs the controls live on (and their armatures' data)."""
    import bpy  # Blender: this module is also read by scene_data, which the command line loads before it

    ids = [mesh, mesh.data, mesh.data.shape_keys]
    for modifier in mesh.modifiers:
        if modifier.type == "ARMATURE" and modifier.object is not None:
            ids += [modifier.object, modifier.object.data]
    for c in controls:
        ids.append(c.owner)
        if isinstance(c.owner, bpy.types.Object) and c.owner.type == "ARMATURE":
            ids.append(c.owner.data)
    seen, out = set(), []
    for id_data in ids:
        if id_data is not None and id(id_data) not in seen:
            seen.add(id(id_data))
            out.append(id_data)
    return out


def unrunnable(ids):
    """[(ID name, data path, what it is, reason)] of the drivers of ``ids`` that Blender could not evaluate at
    the last update (``Driver.is_valid``, ``FCurve.is_valid``; reason "needs Python" when a scripted expression is
    not one Blender evaluates by itself and the file's scripts are not trusted, "gone" when what it drives does
    not exist, else "invalid")."""
    import bpy  # Blender: as above

    trusted = bpy.context.preferences.filepaths.use_scripts_auto_execute
    out = []
    for id_data in ids:
        for fc in _drivers_of(id_data):
            d = fc.driver
            if fc.is_valid and d.is_valid:
                continue
            path = fc.data_path + (f"[{fc.array_index}]" if fc.array_index else "")
            what = f"{path} = {d.expression}" if d.type == "SCRIPTED" else f"{path} ({d.type.lower()})"
            if not fc.is_valid:
                why = "gone"
            elif d.type == "SCRIPTED" and not d.is_simple_expression and not trusted:
                why = "needs Python"
            else:
                why = "invalid"
            out.append((f"{type(id_data).__name__} '{id_data.name}'", fc.data_path, what, why))
    return out


#: Drivers named in the note at most (the count is always given).
NAMED = 6
WHY = {"gone": "what it drives does not exist", "needs Python": "a Python expression Blender did not run",
       "invalid": "a broken expression or variable"}


def unrunnable_note(found):
    """The one line naming the drivers Blender could not run (``unrunnable``), or None."""
    if not found:
        return None
    named = "; ".join(f"{owner} {what} ({WHY[why]})" for owner, _, what, why in found[:NAMED])
    more = f"; and {len(found) - NAMED} more" if len(found) > NAMED else ""
    line = (f"rig: {len(found)} driver(s) could not be evaluated and are left out of the solve (a driver that could "
            f"not run keeps its last value: a corrective shape it drives is not applied): {named}{more}")
    if any(why == "needs Python" for *_, why in found):
        line += f". A driver that needs the file's own Python runs only where its scripts are trusted: {TRUST}"
    return line
