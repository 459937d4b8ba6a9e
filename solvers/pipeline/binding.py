"""Bind a take's markers to a character's mesh and sample its shape keys there (the ``geometric`` Basis).

``bind_character`` is the one entry point of the command line and the sidebar: by vertex groups
(each marker's group, weighted centroid), by a ``map`` (``character.binding.bind_map``) or by the
``nearest`` surface point once the actor's neutral (stabilised exactly as the solve will) is aligned
to the face (``character.binding.bind_nearest``). A binding by position can be stored
(``binding_record``: per marker the three corner vertices, barycentric weights, distance) and used
again without rebinding (``bind_character(..., record=...)``).
"""

from dataclasses import dataclass, replace

import numpy as np

from ..character.binding import Binding, bind_map, bind_nearest, parse_target
from ..character.binding_map import BindingSettings
from ..character.mesh import binding_sampling, group_sampling, sampled_basis
from ..errors import FacecapError
from ..transforms import rotation_angle_deg
from . import stages

#: Version of the stored record's layout.
RECORD_VERSION = 1


@dataclass(frozen=True, eq=False)
class BoundCharacter:
    """The character as the geometric solve sees it, and how it was bound.

    basis : Basis at the bound markers
    mode : "vertex_groups", "map", "nearest (landmarks)" or "nearest (automatic)"
    markers : {marker: (bound, distance_mm or None)} for every marker of the take
    record : dict or None, the binding as stored in a .blend (map and nearest)
    notes : tuple of str
    """

    basis: object
    mode: str
    markers: dict
    record: dict = None
    notes: tuple = ()

    def report(self):
        """JSON-ready {mode, bound, unbound, markers: {name: {bound, distance_mm}}, scale, rotation_deg, notes}."""
        rec = self.record or {}
        return {"mode": self.mode, "bound": sum(b for b, _ in self.markers.values()),
                "unbound": [n for n, (b, _) in self.markers.items() if not b],
                "markers": {n: {"bound": bool(b), "distance_mm": None if d is None else round(float(d), 3)}
                            for n, (b, d) in self.markers.items()},
                "scale": rec.get("scale"), "rotation_deg": rec.get("rotation_deg"), "notes": list(self.notes)}

    def summary(self):
        """One line: mode, bound count, median and worst distance."""
        d = [x for b, x in self.markers.values() if b and x is not None]
        text = f"binding {self.mode}: {sum(b for b, _ in self.markers.values())} of {len(self.markers)} markers bound"
        if d:
            text += f", distance to the surface median {np.median(d):.2f} mm, worst {max(d):.2f} mm"
        return text


def bind_character(mesh, markers, settings, binding, *, record=None):
    """Bind ``markers`` (a MarkerSet) to ``mesh`` (a CharacterMesh) as ``binding`` (BindingSettings) says.

    Parameters
    ----------
    settings : RetargetSettings (the stable markers and the neutral: ``nearest`` aligns the neutral
        the solve will use)
    record : dict, optional
        A stored binding (``binding_record``) to use instead of binding again.

    Returns
    -------
    BoundCharacter
    """
    if not isinstance(binding, BindingSettings):
        raise FacecapError("bind_character: binding must be BindingSettings")
    names = tuple(markers.names)
    if record is not None:
        sampling, table, notes = from_record(record, len(mesh.vertices), names)
        return BoundCharacter(sampled_basis(mesh, sampling), record["mode"], table, record, notes)
    if binding.mode == "vertex_groups":
        sampling = group_sampling(mesh, names)
        if len(sampling) < 3:
            raise FacecapError(f"{mesh.name}: only {len(sampling)} of the take's {len(names)} markers have a vertex "
                               "group of the same name (need 3); bind by position: [binding] mode = \"nearest\" "
                               "or \"map\" (docs/binding.md)")
        table = {n: (n in sampling, None) for n in names}
        missing = [n for n in names if n not in sampling]
        notes = (f"{len(missing)} marker(s) have no vertex group on the character: {missing}",) if missing else ()
        return BoundCharacter(sampled_basis(mesh, sampling), "vertex_groups", table, None, notes)
    if binding.mode == "map":
        found = bind_map(mesh.vertices, mesh.triangles, names, binding.targets(), vertex_groups=mesh.vertex_groups,
                         max_distance_mm=binding.max_distance_mm, mm_per_unit=mesh.mm_per_unit)
    else:
        notes = []
        neutral = actor_neutral(markers, settings, notes)
        landmarks = landmark_targets(mesh, binding.landmarks) or None
        found = bind_nearest(mesh.vertices, mesh.triangles, names, neutral, landmarks=landmarks,
                             max_distance_mm=binding.max_distance_mm, mm_per_unit=mesh.mm_per_unit,
                             marker_mm_per_unit=1000.0,
                             motion=None if landmarks else motion_judge(mesh, markers, settings))
        found = replace(found, notes=tuple(notes) + found.notes)
    rec = binding_record(found, n_vertices=len(mesh.vertices), source=markers.source)
    table = {n: (bool(b), None if not np.isfinite(d) else float(d))
             for n, b, d in zip(found.names, found.bound, found.distance_mm)}
    return BoundCharacter(sampled_basis(mesh, binding_sampling(found)), found.mode, table, rec, found.notes)


def actor_neutral(markers, settings, notes):
    """The actor's neutral markers (M, 3), metres, in the stabilised head frame the solve uses; NaN
    rows for markers without one (no sample over the neutral frames). Only the neutral frames are
    stabilised when they are given as ranges (the stable set chosen, not suggested)."""
    if markers.dim != 3:
        raise FacecapError("binding by position needs 3D markers; bind 2D tracks by vertex group or map")
    usable = stages.usable_markers(markers, settings, []).to_units("m")  # bind_nearest names those left out
    ranges = stages.neutral_ranges(settings)
    if ranges and not settings.auto_stable and settings.master is None:
        sel = np.zeros(usable.n_frames, dtype=bool)
        for first, last in ranges:
            sel |= usable.frame_range_mask(first, last)
        if sel.any():
            usable = replace(usable, frames=usable.frames[sel], positions=usable.positions[sel], segments={})
    quiet = replace(settings, head_smoothing=0.0)  # a few neutral frames: nothing to smooth
    stab, _ = stages.stabilise_take(usable, quiet, [])
    neutral, _, _ = stages.normalise_stabilised(stab, quiet, [])
    out = np.full((markers.n_markers, 3), np.nan)
    out[markers.index(usable.names)] = neutral
    return out


#: The motion test of automatic bindings: frames of the take it looks at (evenly spread), and the motion below
#: which (95th percentile over markers and frames, mm) a take is too still to judge a pose by.
MOTION_FRAMES = 600
MOTION_STILL_MM = 1.0
#: ... and the share of those frames, the ones that move most, whose motion it explains.
MOTION_TOP = 0.25


def take_motion(markers, settings):
    """(names, (f, M, 3) motion from the neutral in the stabilised head frame, metres) of up to MOTION_FRAMES
    frames of the take, or None when it cannot be prepared or barely moves."""
    usable = stages.usable_markers(markers, settings, []).to_units("m")
    sel = np.zeros(usable.n_frames, dtype=bool)
    sel[np.linspace(0, usable.n_frames - 1, min(usable.n_frames, MOTION_FRAMES)).astype(int)] = True
    for first, last in stages.neutral_ranges(settings):  # the neutral the solve uses, all of its frames
        sel |= usable.frame_range_mask(first, last)
    sub = replace(usable, frames=usable.frames[sel], positions=usable.positions[sel], segments={})
    try:
        take, _, _ = stages.prepare_take(sub, settings, [])
    except FacecapError:  # the solve says why; the binding falls back to the neutral's fit
        return None
    size = np.linalg.norm(take.deltas, axis=2)
    if not np.isfinite(size).any() or np.nanpercentile(size, 95) * 1e3 < MOTION_STILL_MM:
        return None
    return tuple(take.names), take.deltas


def motion_judge(mesh, markers, settings):
    """``motion(binding)`` for ``bind_nearest``: the share of the take's motion (``take_motion``) that the
    character's shapes at the binding's points explain (``explained_share``, the motion turned into the
    character's frame); None without motion to judge by."""
    found = take_motion(markers, settings)
    if found is None:
        return None
    names, deltas = found

    def explained(binding):
        basis = sampled_basis(mesh, binding_sampling(binding))
        cols = [names.index(n) for n in basis.marker_names if n in names]
        if len(cols) < 3:
            return None
        rows = [basis.marker_names.index(names[c]) for c in cols]
        D = (deltas[:, cols] @ binding.similarity.rotation.T).reshape(len(deltas), -1)  # scale: no matter
        A = basis.deltas[:, rows].reshape(basis.n_shapes, -1).T
        return explained_share(A, D)

    return explained


def explained_share(A, D, *, sweeps=60, top=MOTION_TOP):
    """The share of the motion ``D`` (f, P; NaN where a marker is missing) that non-negative weights of the
    shapes ``A`` (P, K) explain, over the ``top`` share of frames that move most (where the motion stands
    above the markers' noise): shapes only push one way, so a pose that needs them negative (upside down,
    mirrored) explains little. Coordinate descent on each frame's normal equations; None without motion."""
    seen = np.isfinite(D)
    D = np.where(seen, D, 0.0)
    size = np.sqrt(np.sum(D * D, axis=1) / np.maximum(seen.sum(axis=1), 1))
    keep = (seen.sum(axis=1) >= 9) & (size > 0)
    if keep.sum() < 10:
        return None
    keep &= size >= np.percentile(size[keep], 100 * (1 - top))
    D, m = D[keep], seen[keep].astype(np.float64)
    G = np.einsum("pk,fp,pl->fkl", A, m, A)  # each frame's normal matrix over the markers it has
    B = D @ A
    diag = np.maximum(np.einsum("fkk->fk", G), 1e-12 * max(float(np.max(G)), 1e-300))
    W = np.zeros_like(B)
    for _ in range(sweeps):
        for k in range(A.shape[1]):
            step = (np.einsum("fl,fl->f", W, G[:, :, k]) - B[:, k]) / diag[:, k]
            W[:, k] = np.maximum(0.0, W[:, k] - step)
    residual = np.sum(D * D) - 2 * np.sum(W * B) + np.einsum("fk,fkl,fl->", W, G, W)
    return float(1.0 - residual / np.sum(D * D))


def landmark_targets(mesh, landmarks):
    """{marker: vertex index or (3,) point} of ``landmarks`` ((marker, target text), ...); a vertex
    group is its weighted centroid."""
    out = {}
    for marker, text in landmarks:
        target = parse_target(text)
        if isinstance(target, str):
            if target not in mesh.vertex_groups:
                raise FacecapError(f"landmark {marker!r}: no vertex group {target!r} on {mesh.name} "
                                   "(give a vertex group or a vertex index)")
            idx, w = mesh.vertex_groups[target]
            target = w @ mesh.vertices[idx]
        out[marker] = target
    return out


def binding_record(binding, *, n_vertices, source=""):
    """A binding by position as plain lists (stored in a .blend): mode, marker names, per marker the
    triangle's corner vertices, barycentric weights, distance (mm, -1 when unknown) and bound flag,
    the similarity's scale and rotation, the notes, and the mesh's vertex count it belongs to."""
    if not isinstance(binding, Binding):
        raise FacecapError("binding_record needs a Binding")
    tri = np.where(binding.bound, binding.triangles, 0)
    corners = np.where(binding.bound[:, None], binding.mesh_triangles[tri], -1)
    sim = binding.similarity
    return {"version": RECORD_VERSION, "mode": binding.mode, "names": list(binding.names),
            "corners": corners.astype(int).ravel().tolist(),
            "barycentric": np.nan_to_num(binding.barycentric, nan=0.0).ravel().tolist(),
            "distance_mm": np.nan_to_num(binding.distance_mm, nan=-1.0).tolist(),
            "bound": [int(b) for b in binding.bound], "n_vertices": int(n_vertices),
            "scale": None if sim is None else float(sim.scale),
            "rotation_deg": None if sim is None else float(rotation_angle_deg(sim.rotation)),
            "notes": list(binding.notes), "source": str(source)}


def from_record(record, n_vertices, names=None):
    """(sampling {marker: (corners, barycentric)}, {marker: (bound, distance)}, notes) of a stored
    binding; FacecapError when it belongs to a mesh with another vertex count. Markers of ``names``
    (the take) the record does not hold are unbound."""
    try:
        if int(record.get("version", 0)) != RECORD_VERSION:
            raise FacecapError(f"stored binding: layout version {record.get('version')}, expected {RECORD_VERSION}")
        stored = [str(n) for n in record["names"]]
        m = len(stored)
        corners = np.asarray(record["corners"], dtype=np.int64).reshape(m, 3)
        bary = np.asarray(record["barycentric"], dtype=np.float64).reshape(m, 3)
        dist = np.asarray(record["distance_mm"], dtype=np.float64).reshape(m)
        bound = np.asarray(record["bound"], dtype=bool).reshape(m)
        count = int(record["n_vertices"])
    except (KeyError, TypeError, ValueError) as exc:
        raise FacecapError(f"stored binding is damaged ({type(exc).__name__}: {exc}); bind the markers again") from None
    if count != n_vertices:
        raise FacecapError(f"the stored binding belongs to a mesh of {count} vertices; the character has "
                           f"{n_vertices}: bind the markers again")
    if bound.any() and (corners[bound].min() < 0 or corners[bound].max() >= n_vertices):
        raise FacecapError("stored binding names vertices the character does not have; bind the markers again")
    sampling = {n: (c, b) for n, c, b, ok in zip(stored, corners, bary, bound) if ok}
    table = {n: (bool(ok), None if d < 0 else float(d)) for n, ok, d in zip(stored, bound, dist)}
    notes = list(record.get("notes", ()))
    if names is not None:
        absent = [n for n in names if n not in table]
        if absent:
            notes.append(f"{len(absent)} marker(s) of the take are not in the stored binding: {absent}")
        table = {n: table.get(n, (False, None)) for n in names}
    return sampling, table, tuple(notes)


__all__ = ["BoundCharacter", "RECORD_VERSION", "actor_neutral", "bind_character", "binding_record", "from_record",
           "landmark_targets"]
