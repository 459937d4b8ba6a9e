"""A range-of-motion session's holds as timeline markers: *Find Poses* puts ``ROM: <label>`` at the middle frame of
each pose it found; the user may drag them; the solve and *Save Performer Profile* read them back as
``[calibration] holds`` ({label: middle frame}) whenever any are on the timeline. The user's other markers are
never touched."""

import math

from ...solvers.errors import FacecapError
from ...solvers.rom.sheets import SHEETS

#: Timeline markers whose name starts with this are the ROM's holds.
PREFIX = "ROM: "


def sheet_poses(settings):
    """The poses of the Solve panel's ROM sheet, or () when none is chosen."""
    return SHEETS.get(settings.calib_sheet, ())


def keeps_scores(settings):
    """Whether the Solve panel's calibration take is a landmark take keeping blendshape scores (a ROM on camera, or
    a take that followed a guide)."""
    coll = settings.calib_collection if settings.calib_source == "COLLECTION" else None
    return coll is not None and "facecap_blendshapes" in coll


def has_rom_take(settings):
    """Whether the Solve panel names a calibration take (the ROM take): a collection of marker empties or a file."""
    if settings.calib_source == "COLLECTION":
        return settings.calib_collection is not None
    return bool(settings.calib_path.strip())


def rom_markers(scene):
    """The scene's ``ROM: `` timeline markers, in timeline order."""
    return sorted((m for m in scene.timeline_markers if m.name.startswith(PREFIX)), key=lambda m: m.frame)


def _read_markers(scene, poses):
    """({label: frame} of the ``ROM: `` markers naming a pose of ``poses``, names of markers naming none, names of
    markers of a pose marked before)."""
    labels = {p.label for p in poses}
    holds, unknown, twice = {}, [], []
    for m in rom_markers(scene):
        label = m.name[len(PREFIX):].strip()
        if label not in labels:
            unknown.append(m.name)
        elif label in holds:
            twice.append(m.name)
        else:
            holds[label] = m.frame
    return holds, unknown, twice


def marker_holds(scene, poses):
    """((label, frame), ...) of the ``ROM: `` markers in the order of ``poses``, or None when none names a pose
    (markers naming none are ``check_rom``'s to refuse)."""
    holds, _, _ = _read_markers(scene, poses)
    return tuple((p.label, float(holds[p.label])) for p in poses if p.label in holds) or None


def check_rom(settings):
    """Refuse, by name, what a solve with the Solve panel's ROM sheet cannot use: no ROM take, a ``ROM: `` marker
    naming no pose of the sheet (the solve would not know what it measures), a pose marked twice."""
    poses = sheet_poses(settings)
    if not poses:
        return
    sheet = settings.calib_sheet
    if not has_rom_take(settings):
        raise FacecapError(f"the ROM sheet '{sheet}' is chosen but no ROM take: choose its marker collection or "
                           "file under Actor calibration, or set the ROM sheet to None (a saved performer profile "
                           "needs no ROM take)")
    _, unknown, twice = _read_markers(settings.id_data, poses)
    if unknown:
        raise FacecapError(f"timeline marker(s) {unknown} name no pose of the ROM sheet '{sheet}': rename or delete "
                           f"them, or run Find Poses again (it replaces every '{PREFIX}' marker); its poses: "
                           f"{[p.label for p in poses]}")
    if twice:
        raise FacecapError(f"pose(s) marked more than once on the timeline: {sorted(set(twice))}; keep one marker "
                           "per pose")


def rom_calibration(settings):
    """``sequence`` and ``holds`` of CalibrationSettings from the Solve panel: the ROM sheet's poses and the frames
    of the ``ROM: `` markers on the timeline (None: none there, the holds are found in the ROM take)."""
    poses = sheet_poses(settings)
    scene = settings.id_data  # Scene.facecap: the scene whose timeline holds the markers
    return {"sequence": poses, "holds": marker_holds(scene, poses) if poses else None}


def place_markers(scene, found):
    """Replace the scene's ``ROM: `` markers by one at the middle frame of each pose ``found`` (a RomPoses);
    returns the new markers. Other markers stay as they are."""
    for m in rom_markers(scene):
        scene.timeline_markers.remove(m)
    made = []
    for pose, middle in zip(found.poses, found.middles):
        if math.isfinite(middle):
            made.append(scene.timeline_markers.new(PREFIX + pose.label, frame=int(math.floor(middle + 0.5))))
    return made
