"""Scene <-> solver adapters for a take: marker empties, settings, keyed results."""

import glob

import numpy as np

from ..solvers.errors import FacecapError
from ..solvers.markers import MarkerSet
from ..solvers.pipeline import RetargetSettings
from ..solvers.shape_options import Region
from ..solvers.transforms import matrix_to_euler_xyz
from . import anim

LOCATION = [("location", 0), ("location", 1), ("location", 2)]


def _patterns(text):
    return tuple(p.strip() for p in text.split(",") if p.strip())


def shape_options(settings):
    """bounds, locks and regions for RetargetSettings from the Solve panel's shape and region lists."""
    bounds = tuple((glob.escape(s.name), s.lower, s.upper) for s in settings.shapes)
    locks = tuple((glob.escape(s.name), s.lock_value) for s in settings.shapes if s.lock)
    regions = []
    for region in settings.regions:
        shapes = tuple(glob.escape(s.name) for s in settings.shapes if s.region == region.name)
        if shapes:
            regions.append(Region(region.name, shapes, _patterns(region.markers) or ("*",)))
    unassigned = tuple(glob.escape(s.name) for s in settings.shapes if not s.region)
    if regions and unassigned:
        regions.append(Region("rest of the face", unassigned, ("*",)))
    return {"bounds": bounds, "locks": locks, "regions": tuple(regions)}


def retarget_settings(settings):
    """Frozen solver settings from the scene's PropertyGroup."""
    stable = tuple(m.name for m in settings.markers if m.stable)
    return RetargetSettings(
        **shape_options(settings),
        stable_markers=stable,
        neutral_frames=(settings.neutral_first, settings.neutral_last),
        strategy=settings.strategy,
        regularisation=settings.regularisation,
        sparsity=settings.sparsity,
        symmetry=settings.symmetry,
        smoothing=(settings.smoothing_first, settings.smoothing_second),
        fine_iterations=settings.fine_iterations,
        head_smoothing=settings.head_smoothing,
    )


def markers_from_collection(settings):
    """Read the take's marker empties back into a MarkerSet (metres); missing keys are gaps."""
    coll = settings.marker_collection
    if coll is None:
        raise FacecapError("no marker collection: import a take first")
    objects = {o.get("facecap_marker", o.name): o for o in coll.objects if o.type == "EMPTY"}
    names = [m.name for m in settings.markers if m.name in objects] or sorted(objects)
    if not names:
        raise FacecapError(f"collection '{coll.name}' holds no marker empties")
    tracks = [anim.read_curves(objects[n], LOCATION) for n in names]
    frames = np.unique(np.concatenate([f for f, _ in tracks]))
    if frames.size == 0:
        raise FacecapError(f"the marker empties in '{coll.name}' have no keys")
    pos = np.full((frames.size, len(names), 3), np.nan)
    for m, (f, v) in enumerate(tracks):
        pos[np.searchsorted(frames, f), m] = v
    return MarkerSet(tuple(names), frames, pos, fps=settings.fps, units="m", source=f"collection '{coll.name}'")


DIAGNOSTIC_CURVES = ("facecap_residual_mm", "facecap_at_bound")


def key_weights(obj, result, action_name):
    """Key the solved weights on ``obj``'s shape keys in a new action; returns the action.

    The same action carries the per-frame diagnostics as custom-property curves on the shape-key
    datablock (``facecap_residual_mm``, ``facecap_at_bound``), visible in the Graph Editor.
    """
    key = obj.data.shape_keys
    if key is None:
        raise FacecapError(f"object '{obj.name}' has no shape keys")
    for prop in DIAGNOSTIC_CURVES:
        key[prop] = 0.0
    curves = [(f'key_blocks["{n}"].value', 0) for n in result.shape_names]
    curves += [(f'["{p}"]', 0) for p in DIAGNOSTIC_CURVES]
    values = np.column_stack([result.weights, result.residual_rms * 1e3, result.at_bound.astype(np.float64)])
    return anim.new_action_with_curves(key, name=action_name, curves=curves, frames=result.frames, values=values)


def key_head_motion(scene, stab, name):
    """An empty keyed with the removed head motion (location + unwrapped Euler rotation)."""
    import bpy

    head = bpy.data.objects.new(name, None)
    head.empty_display_type = "ARROWS"
    head.empty_display_size = 0.05
    scene.collection.objects.link(head)
    Rh = stab.head_rotations()  # raw = Rh @ stabilised - Rh @ t
    loc = -np.einsum("fij,fj->fi", Rh, stab.translations)
    # Unwrapped so a head turning past 180 deg never flips between frames.
    euler = np.unwrap(matrix_to_euler_xyz(Rh), axis=0)
    values = np.concatenate([loc, euler], axis=1)
    values[stab.flagged] = np.nan
    curves = LOCATION + [("rotation_euler", 0), ("rotation_euler", 1), ("rotation_euler", 2)]
    anim.new_action_with_curves(head, name=name, curves=curves, frames=stab.markers.frames, values=values)
    return head
