"""Movie clips -> footage the video tracker reads, and seed points from the clip's own tracks."""

import re
from pathlib import Path

import bpy
import numpy as np

from ..solvers.errors import FacecapError


def clip_footage(clip):
    """(source, frame_offset) for solvers.video.Footage so that its frame numbers are scene frames.

    Videos number frames from 0 in the file; image sequences by the number in the file name. The
    clip starts at ``clip.frame_start`` in the scene.
    """
    path = Path(bpy.path.abspath(clip.filepath))
    if clip.source == "SEQUENCE":
        match = re.search(r"(\d+)(\.[^.]+)$", path.name)
        if not match:
            raise FacecapError(f"movie clip '{clip.name}': cannot find the frame number in '{path.name}'")
        first = int(match.group(1))
        pattern = str(path.parent / (path.name[: match.start(1)] + "*" + match.group(2)))
        return pattern, clip.frame_start - first
    return str(path), clip.frame_start


def clip_seeds(clip, frame):
    """Names and pixel positions (origin top-left) of the clip's enabled track markers at ``frame``."""
    width, height = clip.size
    names, points = [], []
    for track in clip.tracking.objects.active.tracks:
        marker = track.markers.find_frame(frame, exact=True)
        if marker is None or marker.mute:
            continue
        names.append(track.name)
        points.append((marker.co[0] * width, (1.0 - marker.co[1]) * height))
    return names, np.array(points, dtype=np.float64).reshape(-1, 2)
