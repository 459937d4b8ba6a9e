"""The drivers of a rig that Blender could not evaluate, named before the solve.

A .blend from someone else opens with its Python scripts not trusted (Blender's Auto Run Python Scripts is off,
and facecap never turns it on): a driver whose expression needs more Python than Blender's restricted set (a
function the file's text module registers, ``__import__``) is not run, and neither is a broken one (a syntax
error, a variable whose target is gone). What such a driver moves stays where it is, so the solve sees the rig
without it: a corrective shape it drives is left out. Blender marks every driver it failed to evaluate
(``Driver.is_valid``, ``FCurve.is_valid``; a file's drivers get a fresh chance when it is opened), so after the
rig has been evaluated (the probes, or the pose library) ``unrunnable_drivers`` lists the drivers of the IDs
that move the bound points, and ``left_out_warning`` is the solve's warning naming them and how to have them run.
"""

import bpy

#: Drivers named in the warning at most (the count is always given)
NAMED = 6


def rig_ids(mesh, controls):
    """The IDs whose drivers move ``mesh``'s points: the mesh, its data and shape keys, its armatures (object and
    data), and the IDs the controls live on."""
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


def unrunnable_drivers(mesh, controls):
    """["<ID> <data path>: <expression> (why)"] of the drivers of ``rig_ids`` that Blender could not evaluate."""
    found = []
    for id_data in rig_ids(mesh, controls):
        ad = getattr(id_data, "animation_data", None)
        if ad is None:
            continue
        for fc in ad.drivers:
            driver = fc.driver
            if fc.is_valid and driver.is_valid:
                continue
            where = f"{type(id_data).__name__} '{id_data.name}' {fc.data_path}" + (
                f"[{fc.array_index}]" if fc.array_index else "")
            if not fc.is_valid:
                why = "what it drives does not exist"
            elif driver.type == "SCRIPTED" and not driver.is_simple_expression:
                why = "a Python expression Blender did not run: the file's scripts are not trusted, or it fails"
            else:
                why = "Blender cannot evaluate it: a broken expression or variable"
            expression = f" = {driver.expression}" if driver.type == "SCRIPTED" else f" ({driver.type.lower()})"
            found.append(f"{where}{expression} ({why})")
    return found


def left_out_warning(found):
    """The solve's warning about the drivers ``unrunnable_drivers`` found."""
    more = f"; and {len(found) - NAMED} more" if len(found) > NAMED else ""
    named = "; ".join(found[:NAMED])
    return (f"rig: {len(found)} driver(s) could not be evaluated and are left out of the solve (what they drive does "
            f"not follow the controls: a corrective shape they drive is not applied): {named}{more}. A driver that "
            "needs the file's own Python runs only where its scripts are trusted: if you trust its author, allow "
            "Auto Run Python Scripts (Blender's Preferences > Save & Load) and solve it in the sidebar; facecap's "
            "command line never runs a .blend's scripts. Otherwise fix or remove the drivers")
