"""Bind an actor's markers to points on any character's surface (no vertex groups needed).

Two ways, both ending in a :class:`Binding` (per marker: triangle, barycentric coordinates,
distance to the surface, bound flag):

* ``map`` (:func:`bind_map`): each marker names its target -- a vertex group (weighted centroid,
  projected onto the surface), a vertex index, or an ``(x, y, z)`` point on the neutral.
* ``nearest`` (:func:`bind_nearest`): the actor's neutral markers are aligned to the character's
  neutral surface by a similarity (scale, rotation, translation) -- from at least three
  ``landmarks`` (marker -> vertex index or point), or without them by a multi-start search over
  rotations, the poses that fit the neutral told apart by how much of the take's motion the
  character's shapes explain there (refused when none or two do) -- refined by robust
  point-to-plane ICP; each marker is then bound to its closest surface point. Markers farther
  than ``max_distance_mm`` from the surface, or without a neutral position, stay unbound.

The pipeline uses ``binding.points(vertices)`` (M, 3) for the bound points on the neutral and
``binding.sample(deltas)`` (K, M, 3) for the shape-key deltas at those points.
"""

from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import FacecapError
from ..options import default
from ..transforms import Similarity, rotation_angle_deg
from .alignment import (CANDIDATES, DISTINCT_DEG, FLOOR_MM, NO_FIT_MM, SEARCH_SCALE_RANGE, SEARCH_SCALES,
                        align_automatic, align_landmarks, automatic_poses, refine)
from .surface import closest_points, interpolate, make_surface, skin_triangles, triangulate

#: A bound marker farther than this from the surface (mm) stays unbound (the default).
MAX_DISTANCE_MM = default("binding.max_distance_mm")


@dataclass(frozen=True, eq=False)
class Binding:
    """Where each marker sits on the character.

    Attributes
    ----------
    names : tuple of str, length M
    triangles : ndarray (M,) int
        Triangle of each marker's bound point (-1 when unbound).
    barycentric : ndarray (M, 3)
        Barycentric coordinates in that triangle (NaN when unbound).
    distance_mm : ndarray (M,)
        Distance from the (aligned) marker or target to the surface, mm; NaN without a position.
    bound : ndarray (M,) bool
    similarity : Similarity or None
        Actor -> character transform (``nearest``); None for ``map``.
    mode : str
        "map", "nearest (landmarks)" or "nearest (automatic)".
    mesh_triangles : ndarray (T, 3)
        The triangles the indices refer to.
    notes : tuple of str
    """

    names: tuple
    triangles: np.ndarray
    barycentric: np.ndarray
    distance_mm: np.ndarray
    bound: np.ndarray
    similarity: Similarity = None
    mode: str = "map"
    mesh_triangles: np.ndarray = None
    notes: tuple = field(default_factory=tuple)

    @property
    def bound_names(self):
        return tuple(n for n, b in zip(self.names, self.bound) if b)

    def points(self, vertices):
        """(M, 3) bound points on a mesh with the character's topology (NaN for unbound markers)."""
        return self.sample(np.asarray(vertices, dtype=np.float64)[None])[0]

    def sample(self, per_vertex):
        """Per-vertex values (K, V, D) -- shape-key deltas -- at the bound points: (K, M, D), NaN where unbound."""
        per_vertex = np.asarray(per_vertex, dtype=np.float64)
        out = np.full(per_vertex.shape[:-2] + (len(self.names), per_vertex.shape[-1]), np.nan)
        ok = self.bound
        if ok.any():
            out[..., ok, :] = interpolate(per_vertex, self.mesh_triangles, self.triangles[ok], self.barycentric[ok])
        return out

    def report(self):
        """JSON-ready {mode, markers: {name: {bound, distance_mm, triangle}}, scale, rotation_deg, notes}."""
        sim = self.similarity
        return {
            "mode": self.mode,
            "markers": {n: {"bound": bool(b), "distance_mm": None if not np.isfinite(d) else round(float(d), 3),
                            "triangle": int(t)} for n, b, d, t in zip(self.names, self.bound, self.distance_mm,
                                                                     self.triangles)},
            "scale": None if sim is None else float(sim.scale),
            "rotation_deg": None if sim is None else float(rotation_angle_deg(sim.rotation)),
            "notes": list(self.notes),
        }


def sample_basis(binding, deltas):
    """Shape-key deltas (K, V, 3) sampled at the bound points: (K, M, 3) (NaN rows for unbound markers)."""
    return binding.sample(deltas)


# ---------------------------------------------------------------------------------------------
# map


def parse_target(text):
    """A map target: int (vertex index), (3,) float array (a point), or str (a vertex group)."""
    if isinstance(text, (int, np.integer)):
        return int(text)
    if not isinstance(text, str):
        point = np.asarray(text, dtype=np.float64)
        if point.shape != (3,) or not np.isfinite(point).all():
            raise FacecapError(f"binding target {text!r}: expected a vertex group, a vertex index or x,y,z")
        return point
    cells = [c.strip() for c in text.strip().strip("()[]").split(",")]
    if len(cells) == 1 and cells[0].lstrip("+").isdigit():
        return int(cells[0])
    if len(cells) == 3:
        try:
            return parse_target([float(c) for c in cells])
        except ValueError:
            pass
    if not text.strip():
        raise FacecapError("binding target is empty: expected a vertex group, a vertex index or x,y,z")
    return text.strip()


def bind_map(vertices, triangles, names, targets, *, vertex_groups=None, max_distance_mm=MAX_DISTANCE_MM,
             mm_per_unit=1000.0):
    """Bind each marker to the target the user named (``mode = "map"``).

    Parameters
    ----------
    vertices : ndarray (V, 3)
        The character's neutral mesh.
    triangles : ndarray (T, 3) or list of polygons
    names : sequence of str, length M
    targets : dict
        ``{marker: target}``; a target is a vertex group name, a vertex index or an (x, y, z)
        point on the neutral (see :func:`parse_target`; strings are parsed). Markers not in
        ``targets`` stay unbound.
    vertex_groups : dict or None
        ``{group name: (vertex indices (n,), weights (n,))}`` of the character.
    max_distance_mm : float
        A point or group centroid farther than this from the surface stays unbound.
    mm_per_unit : float
        Millimetres per mesh unit (1000 for metres).

    Returns
    -------
    Binding
    """
    surface = make_surface(vertices, triangles)
    names = tuple(names)
    unknown = sorted(set(targets) - set(names))
    if unknown:
        raise FacecapError(f"binding map names marker(s) {unknown[:10]} that the take does not have")
    m = len(names)
    tri, bary = np.full(m, -1), np.full((m, 3), np.nan)
    dist = np.full(m, np.nan)
    notes = []
    for i, name in enumerate(names):
        if name not in targets:
            continue
        target = parse_target(targets[name])
        if isinstance(target, int):
            tri[i], bary[i] = _at_vertex(surface, target, name)
            dist[i] = 0.0
            continue
        point = _group_centroid(surface, target, vertex_groups, name) if isinstance(target, str) else target
        t, b, _, d = closest_points(surface, point[None])
        tri[i], bary[i], dist[i] = t[0], b[0], d[0] * mm_per_unit
    bound = tri >= 0
    far = bound & (dist > max_distance_mm)
    if far.any():
        notes.append(_far_note(names, dist, far, max_distance_mm, "target"))
        tri[far], bary[far] = -1, np.nan
        bound &= ~far
    missing = [n for n in names if n not in targets]
    if missing:
        notes.append(f"{len(missing)} marker(s) not in the map stay unbound: {_few(missing)}")
    return Binding(names, tri, bary, dist, bound, None, "map", surface.triangles, tuple(notes))


def _at_vertex(surface, index, name):
    if not 0 <= index < len(surface.vertices):
        raise FacecapError(f"binding target of {name!r}: vertex {index} does not exist "
                           f"(the mesh has {len(surface.vertices)})")
    tris = surface.vertex_triangles[index]
    tris = tris[tris >= 0]
    if tris.size == 0:
        raise FacecapError(f"binding target of {name!r}: vertex {index} is in no face")
    corner = int(np.flatnonzero(surface.triangles[tris[0]] == index)[0])
    bary = np.zeros(3)
    bary[corner] = 1.0
    return int(tris[0]), bary


def _group_centroid(surface, group, vertex_groups, name):
    if not vertex_groups or group not in vertex_groups:
        raise FacecapError(f"binding target of {name!r}: no vertex group {group!r} on the character")
    idx, w = vertex_groups[group]
    idx, w = np.asarray(idx, dtype=np.int64), np.asarray(w, dtype=np.float64)
    if idx.size == 0 or w.sum() <= 0:
        raise FacecapError(f"binding target of {name!r}: vertex group {group!r} is empty")
    return (w[:, None] * surface.vertices[idx]).sum(axis=0) / w.sum()


def _few(names, limit=8):
    names = list(names)
    return ", ".join(names[:limit]) + (f" and {len(names) - limit} more" if len(names) > limit else "")


def _far_note(names, dist, far, limit, what):
    shown = [f"{n} {d:.1f} mm" for n, d, f in zip(names, dist, far) if f]
    hint = ("markers off the face, such as a head band, still stabilise; to bind them raise [binding] max_distance_mm"
            if what == "marker" else "check those rows of the [binding] map")
    return f"warning: {int(far.sum())} {what}(s) farther than {limit:g} mm from the surface stay unbound: {_few(shown)} ({hint})"


# ---------------------------------------------------------------------------------------------
# nearest


def bind_nearest(vertices, triangles, names, markers, *, landmarks=None, max_distance_mm=MAX_DISTANCE_MM,
                 mm_per_unit=1000.0, marker_mm_per_unit=1000.0, allow_scale=True, motion=None):
    """Align the actor's neutral markers to the character's surface and bind each to its closest point.

    Parameters
    ----------
    vertices : ndarray (V, 3)
        The character's neutral mesh (mesh units, ``mm_per_unit`` mm each).
    triangles : ndarray (T, 3) or list of polygons
    names : sequence of str, length M
    markers : ndarray (M, 3)
        The actor's neutral marker positions (``marker_mm_per_unit`` mm per unit); NaN rows
        (no neutral position) stay unbound.
    landmarks : dict or None
        ``{marker: vertex index or (x, y, z) point on the neutral}``, at least three pairs
        that are not collinear; None aligns automatically (multi-start, refusing when ambiguous).
    max_distance_mm : float
        Aligned markers farther than this from the surface stay unbound.
    mm_per_unit, marker_mm_per_unit : float
        Millimetres per mesh unit (1000: metres) and per marker unit (1: a C3D in mm). The
        automatic search expects faces of about the same physical size (within 0.7-1.4x).
    allow_scale : bool
        Fit a uniform scale (the actor's face and the character's differ in size).
    motion : callable or None
        ``motion(binding)`` -> the share of the take's motion the character's shapes explain at that
        binding's points (or None: the take does not move enough to tell). Given, the automatic search
        chooses among the poses that fit the neutral by it (:func:`choose_by_motion`): a face curve of
        68 landmarks fits a stylised face's surface as well upside down as upright.

    Returns
    -------
    Binding
        ``similarity`` maps actor marker units to mesh units.
    """

    tris = np.asarray(triangles) if isinstance(triangles, np.ndarray) else triangulate(triangles)
    surface = make_surface(vertices, tris)  # the alignment sees the whole face, eyeballs in their sockets too
    names = tuple(names)
    markers = np.asarray(markers, dtype=np.float64)
    if markers.shape != (len(names), 3):
        raise FacecapError(f"binding: markers must have shape ({len(names)}, 3); got {markers.shape}")
    have = np.isfinite(markers).all(axis=1)
    notes = []
    if not have.all():
        notes.append(f"warning: {int((~have).sum())} marker(s) have no neutral position and stay unbound: "
                     f"{_few([n for n, h in zip(names, have) if not h])}")
    unit = 1.0 / mm_per_unit  # one millimetre in mesh units
    prior_scale = marker_mm_per_unit / mm_per_unit  # same-size faces in their own units
    skin = make_surface(vertices, skin_triangles(len(vertices), tris))  # a marker sits on skin: not an eyeball

    def bind_at(start, mode, notes):
        sim, fit = refine(surface, markers[have], start, unit=unit, allow_scale=allow_scale)
        if mode == "nearest (automatic)":
            check_automatic_pose(surface, sim, markers[have], prior_scale, allow_scale=allow_scale)
        m = len(names)
        tri, bary, dist = np.full(m, -1), np.full((m, 3), np.nan), np.full(m, np.nan)
        t, b, _, d = closest_points(skin, sim.apply(markers[have]))
        tri[have], bary[have], dist[have] = t, b, d * mm_per_unit
        bound = have.copy()
        far = bound & (dist > max_distance_mm)
        notes = list(notes) + [fit]
        if far.any():
            notes.append(_far_note(names, dist, far, max_distance_mm, "marker"))
            tri[far], bary[far] = -1, np.nan
            bound &= ~far
        return Binding(names, tri, bary, dist, bound, sim, mode, skin.triangles, tuple(notes))

    if not landmarks:
        mode = "nearest (automatic)"
        if motion is not None:
            poses, h = automatic_poses(surface, markers[have], unit=unit, scale=prior_scale, allow_scale=allow_scale)
            found = choose_by_motion(poses, h, lambda start: bind_at(start, mode, notes), motion)
            if found is not None:
                binding, search = found
                return replace(binding, notes=binding.notes[:len(notes)] + (search,) + binding.notes[len(notes):])
        start, search = align_automatic(surface, markers[have], unit=unit, scale=prior_scale,
                                        allow_scale=allow_scale)
        return bind_at(start, mode, notes + [search])
    pairs = _landmark_pairs(surface, names, markers, landmarks)
    start = align_landmarks(pairs, allow_scale=allow_scale)
    found = bind_at(start, "nearest (landmarks)", notes)
    before = np.linalg.norm(start.apply(pairs[1]) - pairs[2], axis=1) * mm_per_unit
    after = np.linalg.norm(found.similarity.apply(pairs[1]) - pairs[2], axis=1) * mm_per_unit
    note = (f"{len(pairs[0])} landmarks: {before.mean():.1f} mm from their targets by the landmark fit, "
            f"{after.mean():.1f} mm after ICP (worst {after.max():.1f} mm)")
    return replace(found, notes=found.notes[:len(notes) + 1] + (note,) + found.notes[len(notes) + 1:])


#: The motion test of automatic poses (``choose_by_motion``): at most this many distinct poses that fit the
#: neutral are tried, those within MOTION_FIT_FACTOR of the best fit's distance. On the realism benchmark's ICT
#: actors (onto the sample character and another ICT face; 18 draws) and on Facial-Sing, every pose kept was
#: upright and explained 30-97% of the take's motion, the poses turned away 0-21% (docs/binding.md): a pose
#: explaining less than MOTION_MIN is no binding, and two poses more than SAME_POSE_DEG apart within
#: MOTION_MARGIN of each other cannot be told apart.
MOTION_POSES = 4
MOTION_FIT_FACTOR = 2.0
MOTION_MIN = 0.25
MOTION_MARGIN = 0.15
SAME_POSE_DEG = 45.0
#: A pose is upside down when it turns the capture's +Z or +Y (a file is Z up, or Y up when it was not
#: converted) this close to the character's down (cosine). An actor's neutral is usually upright in the
#: capture volume, and upside down a jaw that drops looks like brows that rise: such a pose is kept only when
#: it explains UPRIGHT_MARGIN more of the motion than the best upright pose (a head-mounted camera's frame
#: may have any orientation). On the realism benchmark with its actors rolled at random, one face turned over
#: explained 92% against the upright one's 72%.
UPSIDE_DOWN_COS = 0.5
UPRIGHT_MARGIN = 0.25


def upside_down(rotation):
    """Whether a pose (its rotation from the capture's axes to the character's) turns the capture's +Z or +Y
    towards the character's down (-Z)."""
    return bool(min(rotation[2, 2], rotation[2, 1]) < -UPSIDE_DOWN_COS)


def choose_by_motion(poses, starts, bind_at, motion):
    """The binding, among the automatic search's distinct ``poses`` that fit the neutral, whose shapes explain
    the most of the take's motion (``motion(binding)``). Returns None when the take does not move enough to
    tell (the caller decides by the fit alone); raises FacecapError when no pose explains the motion or two do
    equally. Returns (Binding, a one-line note)."""
    best_fit = poses[0][0]
    if best_fit > NO_FIT_MM:
        return None  # align_automatic says why
    tried, chosen = [], []
    for fit, sim in poses:
        if len(chosen) == MOTION_POSES or fit > MOTION_FIT_FACTOR * best_fit + FLOOR_MM:
            break
        if any(rotation_angle_deg(sim.rotation @ other.rotation.T) <= DISTINCT_DEG for _, other in chosen):
            continue
        chosen.append((fit, sim))
        try:
            binding = bind_at(sim)
        except FacecapError:  # scale at the end of the search, or on the back of the head
            continue
        share = motion(binding)
        if share is None:
            return None
        tried.append((share, fit, binding))
    if not tried:
        return None
    tried.sort(key=lambda x: -x[0])
    every = tried
    turned_note = ""
    if upside_down(tried[0][2].similarity.rotation):
        upright = next((t for t in tried if not upside_down(t[2].similarity.rotation) and t[0] >= MOTION_MIN
                        and t[0] > tried[0][0] - UPRIGHT_MARGIN), None)
        if upright is not None:  # the face turned over against the capture's up: the upright pose is kept
            turned_note = (f"; the pose that explains {100 * tried[0][0]:.0f}% turns the capture's +Z or +Y down "
                           f"and is left out")
            tried = [upright] + [t for t in tried if not upside_down(t[2].similarity.rotation) and t is not upright]
    share, fit, binding = tried[0]
    if share < MOTION_MIN:
        raise FacecapError(
            f"automatic binding found no pose where the character's shapes move as the markers do: the best of "
            f"{len(tried)} pose(s) that fit the neutral explains {100 * share:.0f}% of the take's motion (a right "
            f"binding explains 30-97%); {LANDMARK_ADVICE}")
    rival = next(((s, b) for s, _, b in tried[1:] if s > share - MOTION_MARGIN and rotation_angle_deg(
        b.similarity.rotation @ binding.similarity.rotation.T) > SAME_POSE_DEG), None)
    if rival is not None:  # (poses a few degrees apart that explain the motion alike are one pose: the best kept)
        angle = float(rotation_angle_deg(rival[1].similarity.rotation @ binding.similarity.rotation.T))
        raise FacecapError(
            f"automatic binding is ambiguous: two poses {angle:.0f} deg apart explain the take's motion almost "
            f"equally ({100 * share:.0f}% and {100 * rival[0]:.0f}%); {LANDMARK_ADVICE}")
    others = ", ".join(f"{100 * s:.0f}%" for s, _, _ in tried[1:])
    note = (f"automatic alignment: {starts} starting rotations, {len(every)} pose(s) fit the neutral "
            f"(trimmed RMS {best_fit:.2f}-{max(f for _, f, _ in every):.2f} mm); the chosen one ({fit:.2f} mm) "
            f"explains {100 * share:.0f}% of the take's motion" + (f" (the others {others})" if others else "")
            + turned_note)
    return binding, note


#: The automatic alignment's scale may end this close (relative) to the ends of its search before the pose
#: is refused as a fit that ran out of scale rather than a face that matched.
SCALE_EDGE = 0.02
#: Landmark advice when the automatic pose is refused.
LANDMARK_ADVICE = ("give at least three landmarks in [binding.landmarks] (marker = a vertex group or vertex index "
                   "of the character), e.g. the markers on the nose tip, the chin and an outer eye corner")


def check_automatic_pose(surface, sim, markers, prior_scale, *, allow_scale=True):
    """Refuse an automatic pose that is certainly wrong: its scale at the end of the search (the fit ran out
    of scale, as a face turned the wrong way does), or the markers on the back of the head (the character
    faces -Y, as in Blender's front view)."""
    if allow_scale:
        low = prior_scale * min(SEARCH_SCALES) / SEARCH_SCALE_RANGE
        high = prior_scale * max(SEARCH_SCALES) * SEARCH_SCALE_RANGE
        if sim.scale <= low * (1 + SCALE_EDGE) or sim.scale >= high * (1 - SCALE_EDGE):
            raise FacecapError(f"automatic binding found no pose that fits: the best one needs the markers scaled "
                               f"{sim.scale / prior_scale:.2f}x, at the end of the search ({low / prior_scale:.2f}-"
                               f"{high / prior_scale:.2f}x; are the units right?); {LANDMARK_ADVICE}")
    tri = closest_points(surface, sim.apply(markers), candidates=CANDIDATES)[0]
    facing = float(np.mean(surface.normals[tri] @ np.array([0.0, -1.0, 0.0])))
    if facing < 0.0:
        raise FacecapError(f"automatic binding put the markers on the back of the head (their surface faces away "
                           f"from the character's front, -Y; mean {facing:+.2f}); {LANDMARK_ADVICE}")


def _landmark_pairs(surface, names, markers, landmarks):
    """(marker rows (L,), actor points (L, 3), character points (L, 3)) of the landmark pairs."""
    rows, src, dst = [], [], []
    for name, target in landmarks.items():
        if name not in names:
            raise FacecapError(f"landmark {name!r} is not a marker of the take")
        i = names.index(name)
        if not np.isfinite(markers[i]).all():
            raise FacecapError(f"landmark {name!r} has no neutral position")
        target = parse_target(target)
        if isinstance(target, str):
            raise FacecapError(f"landmark {name!r}: give a vertex index or x,y,z (vertex groups are resolved "
                               "to points by the caller)")
        if isinstance(target, int):
            if not 0 <= target < len(surface.vertices):
                raise FacecapError(f"landmark {name!r}: vertex {target} does not exist")
            target = surface.vertices[target]
        rows.append(i)
        src.append(markers[i])
        dst.append(target)
    if len(rows) < 3:
        raise FacecapError(f"landmarks: need at least 3 marker -> vertex pairs; got {len(rows)}")
    return np.asarray(rows), np.asarray(src, dtype=np.float64), np.asarray(dst, dtype=np.float64)


__all__ = ["Binding", "MAX_DISTANCE_MM", "bind_map", "bind_nearest", "parse_target", "sample_basis"]
