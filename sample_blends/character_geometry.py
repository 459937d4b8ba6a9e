"""Deterministic geometry of the sample character "Face" (numpy only, no bpy).

Everything here is plain numpy maths so it can be tested without Blender.
``build_character()`` returns the neutral mesh, the 52 ARKit shape-key deltas,
a vertex mirror map and the marker layout. The Blender side lives in
``generate_character.py``.

Conventions: metres, Z up, the face looks down -Y, +X is the subject's left.
The head is a ring/row grid (columns symmetric about the midline, so the
topology is left/right symmetric) whose front is sculpted by smooth bumps.
The eye row and the mouth row are split between their corners, which gives
eye openings with upper/lower lids and a mouth slit with two lips.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from facecap.solvers.io.arkit import ARKIT_52

ARKIT_NAMES = ARKIT_52  # the project's single list of the 52 ARKit names

# Part labels per vertex.
PART_HEAD, PART_EYE_L, PART_EYE_R, PART_TONGUE = 0, 1, 2, 3
# Material slots (index per face).
MATERIALS = ("skin", "sclera", "iris", "tongue", "lips")

# --- proportions (metres) -------------------------------------------------
Z_TOP, Z_BOTTOM = 0.12, -0.105          # crown and the flat underside of the jaw
Z_EYE = 0.005                           # eye slit row
ROW_DZ = 0.0031                         # row spacing over the face
Z_MOUTH = Z_EYE - 20 * ROW_DZ           # mouth slit row (-0.057)
N_ROWS_ABOVE_EYE = 22
N_ROWS_BELOW_MOUTH = 13
N_COLS = 72                             # columns around the head (even)
COL_WARP = 0.6                          # > 0 packs columns towards the face
CAP_SPACING = 0.0065                    # row spacing on the crown and under the jaw
EYE_X, EYE_HALF_W = 0.032, 0.0135       # eye centre x and half width of the slit
EYE_UP_H, EYE_LOW_H = 0.0045, 0.003     # upper / lower lid opening at rest
EYE_R, LID_T = 0.0115, 0.0015           # eyeball radius, lid thickness
MOUTH_HALF_W = 0.025                    # mouth corner x
MOUTH_GAP = 0.0003                      # half gap of the closed lips at rest


@dataclass(frozen=True)
class Marker:
    """One marker: a weighted vertex patch (the pipeline uses its centroid)."""

    name: str
    region: str
    stable: bool
    description: str
    vertices: tuple[int, ...]
    weights: tuple[float, ...]


@dataclass(frozen=True)
class FaceTopology:
    """Landmark bookkeeping used by the shape keys and the markers."""

    part: np.ndarray          # (V,) part label
    row: np.ndarray           # (V,) grid row (-1 off the grid)
    col: np.ndarray           # (V,) grid column (-1 off the grid)
    eye_side: np.ndarray      # (V,) +1 above the eye slit row / upper copy, -1 below, 0 corner
    mouth_side: np.ndarray    # (V,) same for the mouth slit
    eye_row: int
    mouth_row: int
    eye_centre: np.ndarray    # (3,) left eyeball centre
    upper_edge: np.ndarray    # (k,) vertex ids of the left upper lid edge (medial -> lateral)
    lower_edge: np.ndarray    # (k,) vertex ids of the left lower lid edge
    eye_corners: tuple[int, int]    # left inner, outer corner vertex
    mouth_corner: int         # left mouth corner vertex
    upper_lip_edge: np.ndarray
    lower_lip_edge: np.ndarray


@dataclass(frozen=True)
class CharacterGeometry:
    vertices: np.ndarray              # (V, 3) float64 neutral positions
    faces: list[tuple[int, ...]]      # polygons (quads and pole triangles)
    face_material: np.ndarray         # (P,) material slot index
    mirror: np.ndarray                # (V,) index of each vertex's X-mirror
    topology: FaceTopology
    shape_keys: dict[str, np.ndarray] = field(default_factory=dict)   # name -> (V, 3) delta
    markers: tuple[Marker, ...] = ()


# --- small maths helpers -------------------------------------------------
def smoothstep(x, a, b):
    """0 at ``a``, 1 at ``b`` (either order), C1 in between."""
    t = np.clip((np.asarray(x, dtype=float) - a) / (b - a), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def gauss2(x, z, cx, cz, sx, sz):
    return np.exp(-0.5 * ((x - cx) / sx) ** 2 - 0.5 * ((z - cz) / sz) ** 2)


def _profile_r(s):
    """Horizontal scale of the head at normalised height ``s`` in [-1, 1]."""
    s = np.clip(s, -1.0, 1.0)
    top = np.sqrt(np.clip(1.0 - s * s, 0.0, None))
    bottom = np.clip(1.0 - np.abs(s) ** 3.5, 0.0, None) ** (1.0 / 3.5)
    return np.where(s >= 0.0, top, bottom)


_ZC, _H = 0.5 * (Z_TOP + Z_BOTTOM), 0.5 * (Z_TOP - Z_BOTTOM)


def _half_width(z):
    return 0.073 - 0.017 * smoothstep(z, -0.01, -0.095)


def _cap_rows(z_start, z_pole, spacing):
    """Row heights strictly between a face row and a pole, evenly spaced by arc length."""
    s = np.linspace((z_start - _ZC) / _H, (z_pole - _ZC) / _H, 4001)
    pts = np.stack([0.085 * _profile_r(s), _H * s], axis=1)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    n = max(int(round(arc[-1] / spacing)), 2)
    targets = np.linspace(0.0, arc[-1], n + 1)[1:-1]
    return _ZC + _H * np.interp(targets, arc, s)


def row_heights():
    """Row z values from the crown down to the jaw underside (poles excluded)."""
    face = Z_EYE + ROW_DZ * np.arange(N_ROWS_ABOVE_EYE, -(20 + N_ROWS_BELOW_MOUTH) - 1, -1)
    top = _cap_rows(face[0], Z_TOP, CAP_SPACING)[::-1]
    bottom = _cap_rows(face[-1], Z_BOTTOM, CAP_SPACING)
    return np.concatenate([top, face, bottom])


def column_angles():
    """Azimuths; column j and N_COLS - j are mirror images, j = N_COLS/2 faces -Y."""
    u = -np.pi + 2.0 * np.pi * np.arange(N_COLS) / N_COLS
    return u - COL_WARP * np.sin(u)


# --- the sculpt ----------------------------------------------------------
def eye_opening(x):
    """Upper and lower lid offsets (m) of the left eye slit at abscissa ``x``."""
    t = np.clip((np.abs(x) - EYE_X) / EYE_HALF_W, -1.0, 1.0)
    shape = (1.0 - t * t) * (1.0 - 0.12 * t)
    return EYE_UP_H * shape, EYE_LOW_H * (1.0 - t * t)


def _lid_falloff(d):
    return np.exp(-(d / 0.010) ** 2)


def face_relief(x, z):
    """Forward (-Y) relief of the face at (x, z); negative is towards the viewer."""
    ax = np.abs(x)
    d = np.zeros_like(x)
    d += -0.004 * gauss2(ax, z, 0.029, 0.027, 0.013, 0.0055)        # brow ridge
    d += -0.0025 * gauss2(x, z, 0.0, 0.022, 0.009, 0.008)          # glabella
    d += 0.011 * gauss2(ax, z, EYE_X, 0.004, 0.0125, 0.010)         # eye socket
    # nose: bridge deepening towards the tip, cut off under the nostrils
    along = np.clip((0.016 - z) / 0.045, 0.0, 1.0)
    width = 0.0055 + 0.0025 * along
    bridge = -(0.003 + 0.017 * along ** 1.3) * np.exp(-0.5 * (x / width) ** 2)
    bridge *= smoothstep(z, 0.03, 0.016) * smoothstep(z, -0.0395, -0.031)
    d += bridge
    d += -0.0075 * gauss2(x, z, 0.0, -0.0285, 0.0075, 0.0058)        # tip
    d += -0.0065 * gauss2(ax, z, 0.0135, -0.0315, 0.0052, 0.0048)     # nostril wings
    d += -0.0045 * gauss2(ax, z, 0.046, -0.007, 0.012, 0.010)        # cheekbones
    d += -0.002 * gauss2(ax, z, 0.040, -0.035, 0.014, 0.016)         # cheeks
    d += -0.011 * gauss2(x, z, 0.0, -0.060, 0.023, 0.020)            # muzzle
    d += -0.0030 * gauss2(x, z, 0.0, -0.0515, 0.0145, 0.0035)        # upper lip
    d += -0.0038 * gauss2(x, z, 0.0, -0.0625, 0.0135, 0.0042)        # lower lip
    d += 0.0028 * gauss2(x, z, 0.0, Z_MOUTH, 0.016, 0.0014)          # mouth line
    d += 0.0012 * gauss2(x, z, 0.0, -0.0445, 0.0035, 0.004)          # philtrum
    d += 0.0022 * gauss2(x, z, 0.0, -0.0725, 0.013, 0.0035)          # mentolabial fold
    d += -0.016 * gauss2(x, z, 0.0, -0.0875, 0.0150, 0.0100)         # chin
    d += 0.004 * gauss2(ax, z, 0.058, 0.035, 0.010, 0.016)           # temples
    return d


def _eye_centre():
    z = Z_EYE
    th = np.arcsin(EYE_X / (_half_width(z) * _profile_r((z - _ZC) / _H)))
    y_plain = 0.004 - 0.095 * np.cos(th)
    return np.array([EYE_X, y_plain + EYE_R - 0.0005, Z_EYE])


def _apply_lids(x, y, z, centre, front):
    """Pull the skin around the eye onto a sphere slightly larger than the eyeball."""
    dx, dz = np.abs(x) - centre[0], z - centre[2]
    rr = (EYE_R + LID_T) ** 2 - dx * dx - dz * dz
    y_lid = centre[1] - np.sqrt(np.clip(rr, 0.0, None))
    q = (dx / 0.019) ** 2 + (dz / 0.016) ** 2
    w = np.clip(1.0 - q, 0.0, 1.0) ** 2 * front
    y = (1.0 - w) * y + w * y_lid
    # the skin never sinks behind the eyeball (plus lid thickness)
    return np.where((rr > 0.0) & (front > 0.5), np.minimum(y, y_lid), y)


def _head_surface(theta, z, zopen):
    """Positions of head vertices from column angle, row height and eye-slit offsets."""
    zz = z + zopen
    s = (zz - _ZC) / _H
    r = _profile_r(s)
    x = _half_width(zz) * r * np.sin(theta)
    c = np.cos(theta)
    back = 0.100 - 0.030 * smoothstep(zz, -0.02, -0.10)
    depth = np.where(c >= 0.0, 0.095, back)
    y = 0.004 - depth * r * c
    front = smoothstep(c, 0.15, 0.6)
    y = y + front * face_relief(x, zz)
    y = _apply_lids(x, y, zz, _eye_centre(), front)
    return np.stack([x, y, zz], axis=1)


# --- construction --------------------------------------------------------
def _uv_sphere(centre, radii, n_seg, n_ring):
    """Sphere with poles on the Y axis (front pole first); mirror-friendly ring order."""
    verts = [(0.0, -1.0, 0.0)]
    for i in range(1, n_ring):
        a = np.pi * i / n_ring
        for k in range(n_seg):
            p = 2.0 * np.pi * k / n_seg
            verts.append((np.sin(a) * np.sin(p), -np.cos(a), np.sin(a) * np.cos(p)))
    verts.append((0.0, 1.0, 0.0))
    v = np.asarray(verts) * np.asarray(radii) + np.asarray(centre)
    faces = []
    ring = lambda i, k: 1 + (i - 1) * n_seg + (k % n_seg)
    last = len(verts) - 1
    for k in range(n_seg):
        faces.append((0, ring(1, k + 1), ring(1, k)))
        for i in range(1, n_ring - 1):
            faces.append((ring(i, k), ring(i, k + 1), ring(i + 1, k + 1), ring(i + 1, k)))
        faces.append((ring(n_ring - 1, k), ring(n_ring - 1, k + 1), last))
    seg_mirror = [(n_seg - k) % n_seg for k in range(n_seg)]
    mirror = [0] + [1 + (i - 1) * n_seg + seg_mirror[k] for i in range(1, n_ring)
                    for k in range(n_seg)] + [last]
    return v, faces, np.asarray(mirror)


def _orient_outward(verts, faces, centre):
    """Reverse all faces of a closed part if its normals point inwards."""
    total = 0.0
    for f in faces:
        p = verts[list(f)]
        n = np.cross(p[1] - p[0], p[2] - p[0])
        total += float(np.dot(n, p.mean(axis=0) - centre))
    return faces if total > 0 else [tuple(reversed(f)) for f in faces]


def build_head():
    """Head grid: vertices, faces, mirror map and topology bookkeeping arrays."""
    zs = row_heights()
    th = column_angles()
    n_rows, n = len(zs), N_COLS
    eye_row = int(np.argmin(np.abs(zs - Z_EYE)))
    mouth_row = int(np.argmin(np.abs(zs - Z_MOUTH)))
    # plain x at the slit rows, to decide which columns are split
    def x_at(z):
        return _half_width(z) * _profile_r((z - _ZC) / _H) * np.sin(th)
    front = np.cos(th) > 0
    xe, xm = x_at(Z_EYE), x_at(Z_MOUTH)
    eye_cols = np.where(front & (np.abs(np.abs(xe) - EYE_X) < EYE_HALF_W - 1e-4))[0]
    mouth_cols = np.where(front & (np.abs(xm) < MOUTH_HALF_W - 1e-4))[0]

    grid = np.arange(n_rows * n).reshape(n_rows, n) + 1     # index 0 = top pole
    rows = [0]
    cols = [n // 2]
    theta, zrow, zopen, eside, mside = [0.0], [Z_TOP], [0.0], [1], [1]
    for i in range(n_rows):
        for j in range(n):
            rows.append(i); cols.append(j); theta.append(th[j]); zrow.append(zs[i])
            eside.append(int(np.sign(eye_row - i))); mside.append(int(np.sign(mouth_row - i)))
            zopen.append(0.0)
    bottom_pole = len(rows)
    rows.append(n_rows); cols.append(n // 2); theta.append(0.0); zrow.append(Z_BOTTOM)
    eside.append(-1); mside.append(-1); zopen.append(0.0)
    lower_copy = {}
    for j in eye_cols:
        lower_copy[(eye_row, j)] = len(rows)
        rows.append(eye_row); cols.append(j); theta.append(th[j]); zrow.append(zs[eye_row])
        eside.append(-1); mside.append(1); zopen.append(0.0)
    for j in mouth_cols:
        lower_copy[(mouth_row, j)] = len(rows)
        rows.append(mouth_row); cols.append(j); theta.append(th[j]); zrow.append(zs[mouth_row])
        eside.append(1); mside.append(-1); zopen.append(0.0)
    rows, cols = np.asarray(rows), np.asarray(cols)
    theta, zrow = np.asarray(theta), np.asarray(zrow)
    eside, mside = np.asarray(eside), np.asarray(mside)
    # corners of the slits (on the slit row, unsplit) are side 0
    on_eye_row = (rows == eye_row)
    on_mouth_row = (rows == mouth_row)
    split_eye = np.isin(cols, eye_cols) & on_eye_row
    split_mouth = np.isin(cols, mouth_cols) & on_mouth_row
    for idx in np.where(split_eye)[0]:
        if idx < bottom_pole:
            eside[idx] = 1
    for idx in np.where(split_mouth)[0]:
        if idx < bottom_pole:
            mside[idx] = 1
    eside[on_eye_row & ~split_eye] = 0
    mside[on_mouth_row & ~split_mouth] = 0

    # eye slit opening: shift rows near the eye up/down
    x0 = _half_width(zrow) * _profile_r((zrow - _ZC) / _H) * np.sin(theta)
    h_up, h_low = eye_opening(x0)
    near_eye = (np.cos(theta) > 0) & (np.abs(np.abs(x0) - EYE_X) < EYE_HALF_W)
    dz = zrow - Z_EYE
    zopen = np.where(near_eye & (eside > 0), h_up * _lid_falloff(dz), 0.0)
    zopen = np.where(near_eye & (eside < 0), -h_low * _lid_falloff(dz), zopen)
    # mouth slit: a hair's breadth apart so every vertex has a distinct position
    tm = np.clip(x0 / MOUTH_HALF_W, -1.0, 1.0)
    gap = MOUTH_GAP * (1.0 - tm * tm)
    zopen = np.where(split_mouth, np.where(mside > 0, gap, -gap), zopen)

    verts = _head_surface(theta, zrow, zopen)
    verts[0] = (0.0, 0.004, Z_TOP)
    verts[bottom_pole] = (0.0, 0.004, Z_BOTTOM)

    def vid(i, j, below_slit):
        """Vertex of grid cell (i, j); the lower copy when the face lies below a slit."""
        if below_slit and (i, j) in lower_copy:
            return lower_copy[(i, j)]
        return grid[i, j]

    faces = []
    for j in range(n):
        faces.append((0, grid[0, j], grid[0, (j + 1) % n]))
    for i in range(n_rows - 1):
        for j in range(n):
            j1 = (j + 1) % n
            faces.append((vid(i, j, True), vid(i + 1, j, False),
                          vid(i + 1, j1, False), vid(i, j1, True)))
    for j in range(n):
        faces.append((grid[n_rows - 1, j], bottom_pole, grid[n_rows - 1, (j + 1) % n]))
    faces = _orient_outward(verts, faces, np.array([0.0, 0.004, _ZC]))

    colm = (n - cols) % n
    key = {(r, c, s): k for k, (r, c, s) in enumerate(zip(rows, cols, _copy_flag(len(rows), lower_copy)))}
    flags = _copy_flag(len(rows), lower_copy)
    mirror = np.array([key[(r, c, f)] for r, c, f in zip(rows, colm, flags)])
    mirror[0], mirror[bottom_pole] = 0, bottom_pole

    def edge_ids(r, copy):
        cs = sorted((j for j in (eye_cols if r == eye_row else mouth_cols)),
                    key=lambda j: x_at(zs[r])[j])
        return np.array([lower_copy[(r, j)] if copy else grid[r, j] for j in cs])

    def corner(r, cols_split, target):
        xs = x_at(zs[r])
        cand = [j for j in range(n) if front[j] and j not in set(cols_split)]
        return grid[r, min(cand, key=lambda j: abs(xs[j] - target))]

    left_eye = [j for j in eye_cols if xe[j] > 0]
    left_eye.sort(key=lambda j: xe[j])
    up_edge = np.array([grid[eye_row, j] for j in left_eye])
    low_edge = np.array([lower_copy[(eye_row, j)] for j in left_eye])
    mcols = sorted(mouth_cols, key=lambda j: xm[j])
    topo = dict(
        row=rows, col=cols, eye_side=eside, mouth_side=mside, eye_row=eye_row,
        mouth_row=mouth_row, eye_centre=_eye_centre(), upper_edge=up_edge,
        lower_edge=low_edge,
        eye_corners=(corner(eye_row, eye_cols, EYE_X - EYE_HALF_W),
                     corner(eye_row, eye_cols, EYE_X + EYE_HALF_W)),
        mouth_corner=corner(mouth_row, mouth_cols, MOUTH_HALF_W),
        upper_lip_edge=np.array([grid[mouth_row, j] for j in mcols]),
        lower_lip_edge=np.array([lower_copy[(mouth_row, j)] for j in mcols]),
    )
    return verts, faces, mirror, topo


def _copy_flag(nv, lower_copy):
    flag = np.zeros(nv, dtype=int)
    for idx in lower_copy.values():
        flag[idx] = 1
    return flag


def _face_materials(verts, faces, part):
    mats = np.zeros(len(faces), dtype=int)
    for k, f in enumerate(faces):
        p = part[f[0]]
        if p in (PART_EYE_L, PART_EYE_R):
            c = verts[list(f)].mean(axis=0)
            centre = _eye_centre() * np.array([np.sign(c[0]), 1.0, 1.0])
            v = (c - centre) / np.linalg.norm(c - centre)
            mats[k] = 2 if -v[1] > 0.9 else 1
        elif p == PART_TONGUE:
            mats[k] = 3
        else:
            c = verts[list(f)].mean(axis=0)
            ex = np.abs(c[0]) / (MOUTH_HALF_W + 0.001)
            zr = -0.0495 if c[2] > Z_MOUTH else -0.067
            ez = (c[2] - Z_MOUTH) / (zr - Z_MOUTH)
            if c[1] < -0.05 and ex < 1.0 and ez < 1.0 - ex ** 2 * 0.6:
                mats[k] = 4
    return mats


def build_character():
    """Build the whole character deterministically (no randomness anywhere)."""
    hv, hf, hm, topo = build_head()
    parts = [np.full(len(hv), PART_HEAD)]
    verts, faces, mirror = [hv], list(hf), [hm]
    off = len(hv)
    centre = _eye_centre()
    ev, ef, em = _uv_sphere(centre, (EYE_R,) * 3, 16, 10)
    ef = _orient_outward(ev, ef, centre)
    n_eye = len(ev)
    # left eye, then right eye as its exact mirror (same vertex order)
    verts += [ev, ev * np.array([-1.0, 1.0, 1.0])]
    faces += [tuple(off + k for k in f) for f in ef]
    faces += [tuple(off + n_eye + k for k in reversed(f)) for f in ef]
    mirror += [np.arange(n_eye) + off + n_eye, np.arange(n_eye) + off]
    parts += [np.full(n_eye, PART_EYE_L), np.full(n_eye, PART_EYE_R)]
    off += 2 * n_eye
    t_centre = np.array([0.0, -0.068, Z_MOUTH - 0.0075])
    tv, tf, tm = _uv_sphere(t_centre, (0.016, 0.022, 0.0055), 12, 8)
    tf = _orient_outward(tv, tf, t_centre)
    verts.append(tv)
    faces += [tuple(off + k for k in f) for f in tf]
    mirror.append(tm + off)
    parts.append(np.full(len(tv), PART_TONGUE))

    verts = np.concatenate(verts)
    mirror = np.concatenate(mirror)
    part = np.concatenate(parts)
    verts = _symmetrise_positions(verts, mirror)
    nv = len(verts)
    pad = lambda a, fill: np.concatenate([a, np.full(nv - len(a), fill)])
    topology = FaceTopology(
        part=part, row=pad(topo["row"], -1), col=pad(topo["col"], -1),
        eye_side=pad(topo["eye_side"], 0), mouth_side=pad(topo["mouth_side"], 0),
        **{k: v for k, v in topo.items() if k not in ("row", "col", "eye_side", "mouth_side")},
    )
    mats = _face_materials(verts, faces, part)
    keys = compute_shape_keys(verts, topology, mirror)
    markers = build_markers(verts, faces, topology, mirror, keys)
    return CharacterGeometry(verts, faces, mats, mirror, topology, keys, markers)


def _symmetrise_positions(verts, mirror):
    """Make the mirror map exact: average each vertex with its mirrored partner."""
    flip = np.array([-1.0, 1.0, 1.0])
    sym = 0.5 * (verts + verts[mirror] * flip)
    sym[mirror == np.arange(len(verts)), 0] = 0.0
    return sym


# --- shape keys ----------------------------------------------------------
FLIP_X = np.array([-1.0, 1.0, 1.0])
JAW_HINGE = np.array([0.0, 0.012, -0.010])
JAW_OPEN_ANGLE = np.radians(16.0)
EYE_LOOK_ANGLE = np.radians(20.0)


def _bump(q):
    """Compact C2 falloff of a squared normalised distance: exactly 0 for q >= 1."""
    return np.clip(1.0 - q, 0.0, None) ** 3


def _rotate_x(p, centre, angle):
    """Rotate points about the X axis through ``centre``; positive angle lifts the front."""
    ry, rz = p[:, 1] - centre[1], p[:, 2] - centre[2]
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros_like(p)
    out[:, 1] = ry * c + rz * s - ry
    out[:, 2] = rz * c - ry * s - rz
    return out


def _rotate_z(p, centre, angle):
    """Rotate points about the Z axis through ``centre``; positive angle moves the front to +X."""
    rx, ry = p[:, 0] - centre[0], p[:, 1] - centre[1]
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros_like(p)
    out[:, 0] = rx * c - ry * s - rx
    out[:, 1] = rx * s + ry * c - ry
    return out


class _Fields:
    """Per-vertex weight fields shared by the shape-key definitions."""

    def __init__(self, verts, topo):
        self.p = verts
        self.x, self.y, self.z = verts.T
        part = topo.part
        self.head = (part == PART_HEAD).astype(float)
        self.front = self.head * smoothstep(self.y, 0.005, -0.03)
        self.eye_l = (part == PART_EYE_L).astype(float)
        self.tongue = (part == PART_TONGUE).astype(float)
        e = topo.eye_centre
        self.eye = e
        # closing angle of the left eye as a function of x (0 at the corners)
        def elev(ids):
            return np.arctan2(verts[ids, 2] - e[2], -(verts[ids, 1] - e[1]))
        xs = verts[topo.upper_edge, 0]
        inner, outer = verts[topo.eye_corners[0], 0], verts[topo.eye_corners[1], 0]
        close = elev(topo.upper_edge) - elev(topo.lower_edge)
        self.close = np.interp(self.x, np.r_[inner, xs, outer], np.r_[0.0, close, 0.0],
                               left=0.0, right=0.0) * self.head
        self.open_shape = self.close / close.max()
        up_h, low_h = eye_opening(self.x)
        side = topo.eye_side
        d_up = self.z - (e[2] + up_h)
        d_low = (e[2] - low_h) - self.z
        near = self.front * (np.linalg.norm(verts - e, axis=1) < 0.03) * (self.x > 0)
        self.g_up = (side >= 0) * (1.0 - smoothstep(d_up, 0.0, 0.012)) * near
        self.g_low = (side <= 0) * (1.0 - smoothstep(d_low, 0.0, 0.010)) * near
        # lips: +1 on the upper lip side of the slit, -1 on the lower
        ms = np.sign(topo.mouth_side).astype(float)
        lipness = 1.0 - smoothstep(np.abs(self.x), 0.75 * MOUTH_HALF_W, MOUTH_HALF_W + 0.003)
        self.upper = 0.5 + 0.5 * ms * lipness
        self.lower = 1.0 - self.upper
        corner = verts[topo.mouth_corner]
        self.corner = corner
        # jaw weight: lower lip side in the lips, a soft band on the cheeks
        jaw_lips = 1.0 - smoothstep(np.abs(self.x), MOUTH_HALF_W - 0.004, MOUTH_HALF_W + 0.006)
        side_w = np.where(ms < 0, 1.0, np.where(ms > 0, 0.0, 0.5))
        band = smoothstep(self.z, Z_MOUTH + 0.008, Z_MOUTH - 0.016)
        self.jaw = self.head * smoothstep(self.y, 0.03, 0.0) * (
            jaw_lips * side_w + (1.0 - jaw_lips) * band) + self.tongue
        self.above_lid = smoothstep(self.z, Z_EYE + 0.004, Z_EYE + 0.012)

    def b2(self, cx, cz, rx, rz, mirror_x=False):
        """Compact bump over the front of the face in (x, z)."""
        x = np.abs(self.x) if mirror_x else self.x
        return self.front * _bump(((x - cx) / rx) ** 2 + ((self.z - cz) / rz) ** 2)

    def at_corner(self, rx, rz):
        return self.b2(self.corner[0], self.corner[2], rx, rz)

    def left(self, a=0.0, b=0.006):
        return smoothstep(self.x, a, b)

    def upper_lip(self, cx=0.0, rx=0.032, rz=0.015):
        return self.upper * self.b2(cx, Z_MOUTH + 0.003, rx, rz)

    def lower_lip(self, cx=0.0, rx=0.032, rz=0.017):
        return self.lower * self.b2(cx, Z_MOUTH - 0.004, rx, rz)


def _vec(w, v):
    return w[:, None] * np.asarray(v, dtype=float)[None, :]


def _eye_keys(f):
    e, p = f.eye, f.p
    head = f.head[:, None]
    lid_up = lambda a: _rotate_x(p, e, a) * head
    keys = {}
    # A blink also lifts the lower lid slightly (orbicularis closes both lids).
    keys["eyeBlinkLeft"] = lid_up(-f.close * f.g_up) + lid_up(0.12 * f.close * f.g_low)
    keys["eyeWideLeft"] = lid_up(0.45 * f.open_shape * f.g_up)
    # Squinting also bunches the skin at the outer eye corner (crow's feet).
    keys["eyeSquintLeft"] = (lid_up(0.40 * f.close * f.g_low) + lid_up(-0.10 * f.close * f.g_up)
                             + _vec(f.b2(0.034, -0.013, 0.018, 0.011), (0.0, -0.0005, 0.0015))
                             + _vec(f.b2(0.051, 0.004, 0.012, 0.012), (-0.0012, 0.0, 0.0012)))
    ball = f.eye_l[:, None]
    look_lid = f.open_shape
    keys["eyeLookUpLeft"] = (_rotate_x(p, e, EYE_LOOK_ANGLE) * ball
                             + lid_up(0.10 * look_lid * f.g_up + 0.05 * look_lid * f.g_low))
    keys["eyeLookDownLeft"] = (_rotate_x(p, e, -EYE_LOOK_ANGLE) * ball
                               + lid_up(-0.20 * f.close * f.g_up - 0.06 * look_lid * f.g_low))
    lids = f.g_up * look_lid + f.g_low * look_lid
    keys["eyeLookInLeft"] = _rotate_z(p, e, -EYE_LOOK_ANGLE) * ball + _vec(lids, (-0.0006, 0, 0))
    keys["eyeLookOutLeft"] = _rotate_z(p, e, EYE_LOOK_ANGLE) * ball + _vec(lids, (0.0006, 0, 0))
    keys["cheekSquintLeft"] = (_vec(f.b2(0.044, -0.016, 0.022, 0.02) * smoothstep(f.z, Z_EYE + 0.001, Z_EYE - 0.004),
                                    (0.0006, -0.001, 0.0038))
                               + lid_up(0.10 * f.close * f.g_low))
    return keys


def _brow_keys(f):
    keys = {}
    lid = f.above_lid
    inner = 1.0 - smoothstep(f.x, 0.015, 0.045)
    w = f.b2(0.028, 0.031, 0.028, 0.021) * f.left(0.004, 0.012) * lid
    keys["browDownLeft"] = np.stack([-0.0025 * inner * w, 0.0006 * w, -0.0042 * w], axis=1)
    # Frontalis lifts a broad band of the brow: the inner raise carries the mid brow a little,
    # the outer raise carries the mid brow and lower forehead (bony head markers stay still).
    keys["browInnerUp"] = (_vec(f.b2(0.013, 0.032, 0.026, 0.026, mirror_x=True) * lid, (0.0, -0.0003, 0.0052))
                           + _vec(f.b2(0.012, 0.046, 0.030, 0.019, mirror_x=True), (0.0, 0.0, 0.002)))  # forehead skin
    keys["browOuterUpLeft"] = (_vec(f.b2(0.040, 0.031, 0.026, 0.035) * lid, (0.0004, 0.0, 0.0052))
                               + _vec(f.b2(0.030, 0.046, 0.030, 0.019), (0.0, 0.0, 0.0015)))  # forehead skin
    keys["noseSneerLeft"] = (_vec(f.b2(0.0, -0.0285, 0.009, 0.008), (0.0, 0.0, 0.0012))  # tip lifts
                             + _vec(f.b2(0.0135, -0.029, 0.009, 0.011), (0.0006, -0.0004, 0.0032))
                             + _vec(f.b2(0.011, -0.014, 0.007, 0.010), (0.0, -0.0003, 0.0017))
                             + _vec(f.upper_lip(0.012, 0.014, 0.012), (0.0, 0.0, 0.0010)))
    sx = np.sign(f.x)
    w = f.b2(0.046, -0.043, 0.022, 0.027, mirror_x=True)
    keys["cheekPuff"] = np.stack([0.0055 * sx * w, -0.002 * w, 0.0 * w], axis=1)
    return keys


def _mouth_keys(f):
    keys = {}
    sx = np.sign(f.x)
    keys["mouthClose"] = (_vec(f.upper_lip(rz=0.013), (0.0, 0.0, -0.003))
                          + _vec(f.lower_lip(rx=0.033, rz=0.02), (0.0, 0.0, 0.004)))
    side = f.left(-0.004, 0.006)
    keys["mouthPressLeft"] = (_vec(f.upper_lip(0.013, 0.02, 0.009) * side, (0.0, 0.0012, -0.0016))
                              + _vec(f.lower_lip(0.013, 0.02, 0.01) * side, (0.0, 0.0012, 0.0016)))
    keys["mouthRollLower"] = _vec(f.lower_lip(rx=0.03, rz=0.008), (0.0, 0.0028, 0.0022))
    keys["mouthRollUpper"] = _vec(f.upper_lip(rx=0.03, rz=0.008), (0.0, 0.0028, -0.0022))
    keys["mouthShrugLower"] = (_vec(f.lower_lip(rz=0.02), (0.0, -0.001, 0.0028))
                               + _vec(f.b2(0.0, -0.087, 0.022, 0.02), (0.0, -0.0015, 0.0028)))
    keys["mouthShrugUpper"] = _vec(f.upper_lip(rz=0.014), (0.0, -0.001, 0.0026))
    keys["mouthLowerDownLeft"] = _vec(f.lower_lip(0.010, 0.016, 0.016) * f.left(-0.006, 0.004),
                                      (0.0004, -0.0006, -0.0042))
    keys["mouthUpperUpLeft"] = _vec(f.upper_lip(0.011, 0.016, 0.016) * f.left(-0.006, 0.004),
                                    (0.0, -0.0006, 0.0042))
    corners = f.b2(f.corner[0], f.corner[2], 0.012, 0.012, mirror_x=True)
    keys["mouthFunnel"] = (_vec(f.upper_lip(rx=0.036, rz=0.024), (0.0, -0.0055, 0.0018))
                           + _vec(f.lower_lip(rx=0.036, rz=0.024), (0.0, -0.0055, -0.0022))
                           + np.stack([-0.0025 * sx * corners, -0.001 * corners, 0 * corners], 1))
    purse = f.b2(0.0, Z_MOUTH, 0.036, 0.022)
    keys["mouthPucker"] = (np.stack([-0.3 * f.x * purse, -0.0035 * purse, 0 * purse], 1)
                           + _vec(f.upper_lip(rz=0.01), (0.0, 0.0, -0.001))
                           + _vec(f.lower_lip(rz=0.01), (0.0, 0.0, 0.0012)))
    # sideways mouth: the lips slide over the teeth, the leading corner goes back
    w = f.b2(0.0, Z_MOUTH, 0.042, 0.024)
    keys["mouthLeft"] = np.stack([0.005 * w, 0.002 * w * (1.0 + f.x / 0.025), 0.0 * w], 1)
    keys["mouthSmileLeft"] = (_vec(f.at_corner(0.021, 0.021), (0.003, 0.0025, 0.0045))
                              + _vec(f.b2(0.036, -0.030, 0.026, 0.026), (0.0005, -0.0006, 0.002)))
    keys["mouthFrownLeft"] = (_vec(f.at_corner(0.016, 0.018), (0.0005, 0.0, -0.0045))
                              + _vec(f.b2(0.028, -0.076, 0.016, 0.016), (0.0, 0.0, -0.002)))
    keys["mouthStretchLeft"] = (_vec(f.at_corner(0.021, 0.02), (0.005, 0.0015, -0.002))
                                + _vec(f.lower_lip(0.016, 0.015, 0.015) * f.left(), (0.002, 0.0, -0.0015)))
    keys["mouthDimpleLeft"] = _vec(f.at_corner(0.014, 0.014), (0.001, 0.005, 0.0005))
    return keys


def _jaw_keys(f):
    keys = {}
    keys["jawOpen"] = _rotate_x(f.p, JAW_HINGE, -JAW_OPEN_ANGLE * f.jaw)
    # protrusion slides the condyles forward and down the articular eminence
    keys["jawForward"] = _vec(f.jaw, (0.0, -0.004, -0.002))
    # sideways jaw: swings about the left condyle (the right side comes forward)
    keys["jawLeft"] = _rotate_z(f.p, JAW_HINGE + np.array([0.052, 0.0, 0.0]), 0.05 * f.jaw)
    keys["tongueOut"] = _vec(f.tongue, (0.0, -0.018, -0.002))
    return keys


PAIRS = {"jawLeft": "jawRight", "mouthLeft": "mouthRight"}

# Subtle lip, nose and cheek actions scaled to the amplitudes measured on real faces (a lip roll
# hides the vermilion, several mm; a sneer lifts the nostril wing 4-6 mm), so that a 0.3 mm-noise
# marker capture can observe them at all.
STRENGTH = {
    "mouthPressLeft": 2.0, "mouthRollLower": 2.0, "mouthRollUpper": 2.0,
    "mouthShrugLower": 1.8, "mouthShrugUpper": 1.8, "noseSneerLeft": 1.6,
    "cheekSquintLeft": 1.5, "eyeSquintLeft": 1.5, "mouthFrownLeft": 1.5,
    "mouthUpperUpLeft": 1.3, "mouthLowerDownLeft": 1.3,
}


def compute_shape_keys(verts, topo, mirror):
    """Deltas (V, 3) for the 52 ARKit shapes; right keys are exact mirrors of left keys."""
    f = _Fields(verts, topo)
    base = {}
    for part in (_eye_keys, _brow_keys, _mouth_keys, _jaw_keys):
        base.update(part(f))
    keys = {}
    for name in ARKIT_NAMES:
        if name in base:
            d = base[name] * STRENGTH.get(name, 1.0)
            if name.endswith("Left"):
                keys[name] = d
            elif name in PAIRS:
                keys[name] = d
            else:   # a centre shape: make it exactly symmetric
                keys[name] = 0.5 * (d + d[mirror] * FLIP_X)
    for name in ARKIT_NAMES:
        if name.endswith("Left") and name not in PAIRS:
            keys[name[:-4] + "Right"] = keys[name][mirror] * FLIP_X
        elif name in PAIRS:
            keys[PAIRS[name]] = keys[name][mirror] * FLIP_X
    missing = set(ARKIT_NAMES) - set(keys)
    if missing:
        raise RuntimeError(f"shape keys not defined: {sorted(missing)}")
    return {name: keys[name] for name in ARKIT_NAMES}


# --- markers -------------------------------------------------------------
# (base name, sides, region, description, target (x, z) on the subject's left / midline, slit side)
# slit side: "lid_up"/"lid_low"/"lip_up"/"lip_low" restricts the pick to one side of a slit.
_Z_LIP_UP, _Z_LIP_LOW = Z_MOUTH + ROW_DZ, Z_MOUTH - ROW_DZ
MARKER_SPECS = (
    ("head_forehead", "C", "head", "upper forehead, midline", (0.0, 0.070), None),
    ("head_forehead", "LR", "head", "upper forehead above the mid brow", (0.034, 0.066), None),
    ("head_temple", "LR", "head", "temple, behind the outer brow", (0.066, 0.040), None),
    ("head_nose_bridge", "C", "head", "nose bridge between the eyes", (0.0, 0.0), None),
    ("head_side", "LR", "head", "side of the head in front of the ear", (0.071, -0.004), None),
    ("forehead", "LR", "upper", "lower forehead above the brow", (0.026, 0.049), None),
    ("brow_inner", "LR", "upper", "inner end of the brow", (0.014, 0.030), None),
    ("brow_mid", "LR", "upper", "middle of the brow", (0.030, 0.034), None),
    ("brow_outer", "LR", "upper", "outer end of the brow", (0.047, 0.030), None),
    ("eyelid_upper", "LR", "upper", "upper eyelid above the lash line", (EYE_X, Z_EYE + 0.0075), "lid_up"),
    ("eyelid_upper_outer", "LR", "upper", "upper eyelid, outer third", (EYE_X + 0.007, Z_EYE + 0.0065), "lid_up"),
    ("eyelid_lower", "LR", "upper", "lower eyelid below the lash line", (EYE_X, Z_EYE - 0.006), "lid_low"),
    ("eye_outer", "LR", "upper", "outer eye corner skin (crow's feet)", (0.051, 0.004), None),
    ("under_eye", "LR", "upper", "under the eye, top of the cheek", (0.033, -0.013), None),
    ("cheekbone", "LR", "lower", "cheekbone", (0.050, -0.012), None),
    ("cheek", "LR", "lower", "middle of the cheek", (0.045, -0.036), None),
    ("cheek_lower", "LR", "lower", "lower cheek beside the mouth", (0.046, -0.062), None),
    ("nasolabial", "LR", "lower", "nasolabial fold beside the nostril", (0.025, -0.038), None),
    ("nose_side", "LR", "lower", "side of the nose", (0.010, -0.013), None),
    ("nostril", "LR", "lower", "nostril wing", (0.0155, -0.031), None),
    ("nose_tip", "C", "lower", "tip of the nose", (0.0, -0.0285), None),
    ("philtrum", "C", "lower", "philtrum under the nose", (0.0, -0.044), None),
    ("mouth_above", "LR", "lower", "above the mouth corner", (0.022, -0.046), None),
    ("lip_upper", "C", "lower", "upper lip centre", (0.0, _Z_LIP_UP), "lip_up"),
    ("lip_upper", "LR", "lower", "upper lip, inner third", (0.009, _Z_LIP_UP), "lip_up"),
    ("lip_upper_outer", "LR", "lower", "upper lip, outer third", (0.018, _Z_LIP_UP), "lip_up"),
    ("mouth_corner", "LR", "lower", "mouth corner", None, "corner"),
    ("lip_lower", "C", "lower", "lower lip centre", (0.0, _Z_LIP_LOW), "lip_low"),
    ("lip_lower", "LR", "lower", "lower lip, inner third", (0.009, _Z_LIP_LOW), "lip_low"),
    ("lip_lower_outer", "LR", "lower", "lower lip, outer third", (0.018, _Z_LIP_LOW), "lip_low"),
    ("dimple", "LR", "lower", "cheek just outside the mouth corner", (MOUTH_HALF_W + 0.009, Z_MOUTH), None),
    ("mouth_below", "LR", "lower", "below the mouth corner", (0.022, -0.068), None),
    ("chin_upper", "C", "lower", "mentolabial fold above the chin", (0.0, -0.073), None),
    ("chin", "C", "lower", "chin", (0.0, -0.090), None),
    ("chin", "LR", "lower", "side of the chin", (0.016, -0.088), None),
    ("jaw_front", "LR", "lower", "jaw line near the chin", (0.030, -0.086), None),
    ("jaw", "LR", "lower", "jaw line under the cheek", (0.047, -0.077), None),
    ("jaw_angle", "LR", "lower", "jaw towards the angle", (0.060, -0.062), None),
)


def _neighbours(faces, nv):
    nb = [set() for _ in range(nv)]
    for f in faces:
        for a, b in zip(f, f[1:] + f[:1]):
            nb[a].add(b)
            nb[b].add(a)
    return nb


def _patch(v, nb):
    ring = sorted(nb[v])
    return (v, *ring), (0.5, *([0.5 / len(ring)] * len(ring)))


def build_markers(verts, faces, topo, mirror, keys):
    """Pick a vertex patch per marker; head_ markers avoid every vertex any key moves."""
    nb = _neighbours(faces, len(verts))
    moved = np.zeros(len(verts), dtype=bool)
    for d in keys.values():
        moved |= np.abs(d).max(axis=1) > 0.0
    head = topo.part == PART_HEAD
    frontal = head & (verts[:, 1] < 0.0)
    markers = []
    for base, sides, region, desc, target, slit in MARKER_SPECS:
        ok = frontal.copy()
        if sides == "C":
            ok &= verts[:, 0] == 0.0
        else:
            ok &= verts[:, 0] > 0.0
        if slit == "lid_up":
            ok &= topo.eye_side > 0
        elif slit == "lid_low":
            ok &= topo.eye_side < 0
        elif slit == "lip_up":
            ok &= topo.mouth_side > 0
        elif slit == "lip_low":
            ok &= topo.mouth_side < 0
        if region == "head":
            ok &= np.array([not moved[list(nb[k]) + [k]].any() for k in range(len(verts))])
        if slit == "corner":
            v = int(topo.mouth_corner)
        else:
            d2 = (verts[:, 0] - target[0]) ** 2 + (verts[:, 2] - target[1]) ** 2
            if base == "nose_tip":
                d2 = d2 + 0.1 * np.clip(verts[:, 1] - verts[frontal, 1].min(), 0, None) ** 2
            v = int(np.argmin(np.where(ok, d2, np.inf)))
        ids, w = _patch(v, nb)
        stable = region == "head"
        if sides == "C":
            markers.append(Marker(f"{base}_C", region, stable, desc, ids, w))
        else:
            markers.append(Marker(f"{base}_L", region, stable, desc + " (left)", ids, w))
            mids = tuple(int(mirror[k]) for k in ids)
            markers.append(Marker(f"{base}_R", region, stable, desc + " (right)", mids, w))
    return tuple(markers)


def marker_centroids(verts, markers):
    """(M, 3) weighted centroids of the marker patches."""
    return np.array([np.average(verts[list(m.vertices)], axis=0, weights=m.weights)
                     for m in markers])
