"""Put an imported MarkerSet into the scene: empties in a collection per take, segments as timeline markers.

Empties carry ``["facecap_marker"] = name`` and one action each, keyed in bulk through
:func:`anim.new_action_with_curves` (gaps get no key), so :func:`take.markers_from_collection`
reads them back exactly as it reads the empties of ``facecap.import_markers``.
"""

import bpy
import numpy as np

from ...solvers.markers import UNIT_SCALE
from . import anim

LOCATION = [("location", 0), ("location", 1), ("location", 2)]
#: 2D tracks (pixels) are shown in the XZ plane at 1 px = 1 mm, image y pointing down.
PIXEL_SIZE = 0.001


def scene_positions(markers):
    """(F, M, 3) positions in metres for the viewport (2D pixel tracks in the XZ plane)."""
    if markers.dim == 3:
        return markers.to_units("m").positions if markers.units in UNIT_SCALE else markers.positions
    pos = np.zeros(markers.positions.shape[:2] + (3,))
    pos[..., 0] = markers.positions[..., 0] * PIXEL_SIZE
    pos[..., 2] = -markers.positions[..., 1] * PIXEL_SIZE
    pos[np.isnan(markers.positions[..., 0])] = np.nan
    return pos


def pixels_from_scene(pos):
    """Inverse of ``scene_positions`` for a 2D take: (F, M, 3) metres in the XZ plane -> (F, M, 2) px."""
    return np.stack([pos[..., 0], -pos[..., 2]], axis=-1) / PIXEL_SIZE


def create_take(scene, markers, take_name, *, empty_size=0.002, set_scene_range=True):
    """Create ``FaceCap <take_name>`` with one keyed empty per marker; returns the collection.

    Parameters
    ----------
    scene : bpy.types.Scene
    markers : MarkerSet
    take_name : str
    empty_size : float
        Display size of the sphere empties, metres.
    set_scene_range : bool
        Set the scene's frame range and (rounded) fps to the take's.
    """
    pos = scene_positions(markers)
    coll = bpy.data.collections.new(f"FaceCap {take_name}")
    scene.collection.children.link(coll)
    coll["facecap_take"] = take_name
    coll["facecap_source"] = markers.source
    coll["facecap_dim"] = markers.dim  # 2: pixel tracks drawn in the XZ plane, read back as pixels
    for m, name in enumerate(markers.names):
        empty = bpy.data.objects.new(name, None)
        empty.empty_display_type = "SPHERE"
        empty.empty_display_size = empty_size
        empty["facecap_marker"] = name
        coll.objects.link(empty)
        seen = np.flatnonzero(~np.isnan(pos[:, m, 0]))
        if seen.size:
            empty.location = pos[seen[0], m]
        anim.new_action_with_curves(empty, name=f"FC {take_name} {name}", curves=LOCATION,
                                    frames=markers.frames, values=pos[:, m, :])
    add_segment_markers(scene, markers.segments)
    if set_scene_range:
        fit_scene_to_take(scene, markers.frames, markers.fps)
    return coll


def fit_scene_to_take(scene, frames, fps):
    """The scene's frame range and frame rate (``fps`` / ``fps_base``) set to a take's; ``fps`` None
    leaves the rate."""
    frames = np.asarray(frames, dtype=np.float64)
    if frames.size:
        scene.frame_start, scene.frame_end = int(np.floor(frames[0])), int(np.ceil(frames[-1]))
    if fps:
        scene.render.fps = max(1, int(round(fps)))
        scene.render.fps_base = scene.render.fps / fps


def add_segment_markers(scene, segments):
    """Timeline markers ``<label>`` at each segment's first frame and ``<label> end`` at its last."""
    made = []
    for label, spans in segments.items():
        for first, last in spans:
            made.append(scene.timeline_markers.new(label, frame=int(round(first))))
            made.append(scene.timeline_markers.new(f"{label} end", frame=int(round(last))))
    return made


def remember_take(scene, markers, path, coll):
    """Point the sidebar settings at the new take, as File > Import does."""
    settings = scene.facecap
    settings.take_name = path.stem
    settings.markers_path = str(path)
    if markers.units in ("mm", "cm", "m"):
        settings.units = markers.units
    settings.fps = markers.fps
    settings.marker_collection = coll
    settings.markers.clear()
    gaps = markers.gap_counts()
    for name in markers.names:
        item = settings.markers.add()
        item.name = name
        item.gaps = gaps[name]
        item.stable = name.startswith("head")
    first, last = int(markers.frames[0]), int(markers.frames[-1])
    neutral = markers.segments.get("posed_neutral") or markers.segments.get("neutral")
    if neutral:
        settings.neutral_first, settings.neutral_last = int(neutral[0][0]), int(neutral[0][1])
    elif not (first <= settings.neutral_first <= settings.neutral_last <= last):
        settings.neutral_first, settings.neutral_last = first, min(first + 29, last)
