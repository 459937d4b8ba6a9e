"""Marker takes that already live in the scene: animated empties and movie-clip tracks."""

import numpy as np

from ...solvers.errors import FacecapError
from ...solvers.markers import MarkerSet
from . import anim

LOCATION = [("location", 0), ("location", 1), ("location", 2)]


def markers_from_empties(objects, *, fps, source="selected empties"):
    """A MarkerSet (metres) from the keyed locations of animated empties; frames without a key are gaps.

    Unparented empties only: a parent's motion is not in their location curves.
    """
    empties = [o for o in objects if o.type == "EMPTY"]
    if not empties:
        raise FacecapError(f"{source}: no empties")
    parented = [o.name for o in empties if o.parent is not None]
    if parented:
        raise FacecapError(f"{source}: empties {parented} have a parent; unparent them (keep transform) first")
    tracks = [anim.read_curves(o, LOCATION) for o in empties]
    unkeyed = [o.name for o, (f, _) in zip(empties, tracks) if f.size == 0]
    if unkeyed:
        raise FacecapError(f"{source}: empties {unkeyed} have no location keys")
    frames = np.unique(np.concatenate([f for f, _ in tracks]))
    pos = np.full((frames.size, len(empties), 3), np.nan)
    for m, (f, v) in enumerate(tracks):
        pos[np.searchsorted(frames, f), m] = v
    names = tuple(o.get("facecap_marker", o.name) for o in empties)
    return MarkerSet(names, frames, pos, fps=fps, units="m", source=source)


def markers_from_clip(clip, *, tracking_object=None, fallback_fps=None):
    """A 2D MarkerSet in pixels (origin top-left, y down) from a movie clip's tracks.

    Blender stores marker positions normalised to the frame with the origin bottom-left; disabled
    (muted) markers and frames a track has no marker on are gaps. Image sequences have no frame
    rate of their own: ``fallback_fps`` (the scene's) is used for them.
    """
    tracking = clip.tracking
    obj = tracking.objects[tracking_object] if tracking_object else tracking.objects.active
    tracks = list(obj.tracks)
    if not tracks:
        raise FacecapError(f"movie clip '{clip.name}': no tracks in tracking object '{obj.name}'")
    width, height = clip.size
    if width == 0 or height == 0:
        raise FacecapError(f"movie clip '{clip.name}': the footage could not be read (size 0)")
    per_track = []
    for track in tracks:
        n = len(track.markers)
        frames = np.empty(n, dtype=np.int32)
        co = np.empty(2 * n, dtype=np.float32)
        mute = np.empty(n, dtype=bool)
        track.markers.foreach_get("frame", frames)
        track.markers.foreach_get("co", co)
        track.markers.foreach_get("mute", mute)
        per_track.append((frames, co.reshape(n, 2), mute))
    frames = np.unique(np.concatenate([f for f, _, _ in per_track]))
    if frames.size == 0:
        raise FacecapError(f"movie clip '{clip.name}': the tracks have no markers")
    pos = np.full((frames.size, len(tracks), 2), np.nan)
    for m, (f, co, mute) in enumerate(per_track):
        px = np.column_stack([co[:, 0] * width, (1.0 - co[:, 1]) * height])
        px[mute] = np.nan
        pos[np.searchsorted(frames, f), m] = px
    fps = clip.fps or fallback_fps
    if not fps:
        raise FacecapError(f"movie clip '{clip.name}' has no frame rate; give fallback_fps")
    names = tuple(t.name for t in tracks)
    return MarkerSet(names, frames.astype(np.float64), pos, fps=float(fps), units="px", source=f"movie clip '{clip.name}'")
