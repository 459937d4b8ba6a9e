"""Binding markers to any character's surface (``map`` and ``nearest``), on the sample character with
known truth: markers placed on its surface, moved by an actor's scale, rotation, translation and noise."""

import warnings

import numpy as np
import pytest
from realdata_corpus import CORPUS
from shared_data import skip_without
from sample_geometry import geometry_module

from facecap.solvers.character.alignment import rodrigues
from facecap.solvers.character.binding import bind_map, bind_nearest, parse_target, sample_basis
from facecap.solvers.character.surface import (
    closest_on_triangles,
    closest_points,
    make_surface,
    nearest_triangles,
    triangulate,
)
from facecap.solvers.errors import FacecapError

FACIAL_SING = CORPUS / "c3d" / "c3dorg_29_Facial-Sing.c3d"
NOISE_MM = 0.3


@pytest.fixture(scope="module")
def face():
    """(vertices (V, 3) m, triangles (T, 3), names, true bound points (M, 3), vertex per marker, shape deltas)."""
    g = geometry_module().build_character()
    tris = triangulate(g.faces)
    centroids = np.array([(np.asarray(m.weights)[:, None] * g.vertices[list(m.vertices)]).sum(0) / sum(m.weights)
                          for m in g.markers])
    truth = closest_points(make_surface(g.vertices, tris), centroids)[2]  # each marker's patch, on the surface
    vertex = {m.name: int(m.vertices[int(np.argmax(m.weights))]) for m in g.markers}
    deltas = np.stack([g.shape_keys[k] for k in ("jawOpen", "mouthSmileLeft", "browInnerUp")])
    return g.vertices, tris, tuple(m.name for m in g.markers), truth, vertex, deltas


def actor_take(truth, seed):
    """The markers as an actor's capture (mm): a random similarity of the truth plus noise; returns (markers, scale)."""
    rng = np.random.default_rng(seed)
    scale = rng.uniform(0.8, 1.25)  # the character is this much larger than the actor
    R = rodrigues(rng.normal(size=3) * 2.0)  # any orientation
    t = rng.normal(size=3) * 0.5
    markers = ((truth - t) @ R) / scale * 1000.0 + rng.normal(size=truth.shape) * NOISE_MM
    return markers, scale


def test_closest_point_on_triangles_matches_dense_sampling():
    rng = np.random.default_rng(0)
    a, b, c = (rng.normal(size=(400, 3)) for _ in range(3))
    p = rng.normal(size=(400, 3)) * 2
    q, bary = closest_on_triangles(p, a, b, c)
    assert (bary >= -1e-12).all() and np.allclose(bary.sum(axis=1), 1.0)
    np.testing.assert_allclose(q, bary[:, :1] * a + bary[:, 1:2] * b + bary[:, 2:] * c, atol=1e-12)
    u, v = np.meshgrid(np.linspace(0, 1, 201), np.linspace(0, 1, 201))
    keep = (u + v) <= 1
    u, v = u[keep], v[keep]
    dense = a[:, None] + u[None, :, None] * (b - a)[:, None] + v[None, :, None] * (c - a)[:, None]
    best = np.min(np.linalg.norm(dense - p[:, None], axis=2), axis=1)
    got = np.linalg.norm(q - p, axis=1)
    assert (got <= best + 1e-12).all() and (best - got).max() < 0.02  # the grid's spacing bounds its error


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_automatic_binding_recovers_the_true_points(face, seed):
    vertices, tris, names, truth, _, _ = face
    markers, scale = actor_take(truth, seed)
    b = bind_nearest(vertices, tris, names, markers, marker_mm_per_unit=1.0)
    err = np.linalg.norm(b.points(vertices) - truth, axis=1) * 1000
    assert b.bound.all() and b.mode == "nearest (automatic)"
    assert np.median(err) < 0.8 and err.max() < 2.0, (np.median(err), err.max())  # noise 0.3 mm per axis
    assert b.similarity.scale * 1000 == pytest.approx(scale, rel=0.01)
    assert np.median(b.distance_mm) < 0.5


@pytest.mark.parametrize("seed", range(5))
def test_landmark_binding_recovers_the_true_points(face, seed):
    vertices, tris, names, truth, vertex, _ = face
    markers, scale = actor_take(truth, 10 + seed)
    landmarks = {n: vertex[n] for n in ("nose_tip_C", "chin_C", "brow_inner_L", "brow_inner_R")}
    b = bind_nearest(vertices, tris, names, markers, landmarks=landmarks, marker_mm_per_unit=1.0)
    err = np.linalg.norm(b.points(vertices) - truth, axis=1) * 1000
    assert b.bound.all() and b.mode == "nearest (landmarks)"
    assert np.median(err) < 0.8 and err.max() < 2.0, (np.median(err), err.max())
    assert b.similarity.scale * 1000 == pytest.approx(scale, rel=0.01)


def test_markers_off_the_surface_stay_unbound_and_do_not_spoil_the_rest(face):
    vertices, tris, names, truth, vertex, _ = face
    markers, _ = actor_take(truth, 42)
    off = [names.index(n) for n in ("head_side_L", "head_side_R", "head_forehead_C")]
    centre = markers.mean(axis=0)
    markers[off] += (markers[off] - centre) / np.linalg.norm(markers[off] - centre, axis=1, keepdims=True) * 20
    markers[names.index("lip_lower_C")] = np.nan  # no neutral position (a gap over the neutral range)
    landmarks = {n: vertex[n] for n in ("nose_tip_C", "chin_C", "brow_inner_L", "brow_inner_R")}
    for marks in (None, landmarks):
        b = bind_nearest(vertices, tris, names, markers, landmarks=marks, marker_mm_per_unit=1.0, max_distance_mm=8)
        unbound = {n for n, ok in zip(names, b.bound) if not ok}
        assert unbound == {"head_side_L", "head_side_R", "head_forehead_C", "lip_lower_C"}
        err = np.linalg.norm(b.points(vertices) - truth, axis=1)[b.bound] * 1000
        assert np.median(err) < 0.8 and err.max() < 2.0
        assert np.isnan(b.points(vertices)[~b.bound]).all()
        assert any("no neutral position and stay unbound: lip_lower_C" in n for n in b.notes)
        assert any("farther than 8 mm from the surface stay unbound" in n and "head_side_L" in n for n in b.notes), b.notes
        assert (b.distance_mm[off] > 10).all()  # moved 20 mm away from the centroid: 13-17 mm off the surface


def uv_sphere(radius=0.1, n_seg=48, n_ring=24):
    th = np.linspace(0, np.pi, n_ring + 1)[1:-1]
    ph = np.linspace(0, 2 * np.pi, n_seg, endpoint=False)
    v = [[0, 0, radius]] + [[radius * np.sin(a) * np.cos(b), radius * np.sin(a) * np.sin(b), radius * np.cos(a)]
                            for a in th for b in ph] + [[0, 0, -radius]]

    def ring(i, k):
        return 1 + i * n_seg + k % n_seg

    faces = []
    for k in range(n_seg):
        faces.append((0, ring(0, k), ring(0, k + 1)))
        faces += [(ring(i, k), ring(i + 1, k), ring(i + 1, k + 1), ring(i, k + 1)) for i in range(n_ring - 2)]
        faces.append((ring(n_ring - 2, k), len(v) - 1, ring(n_ring - 2, k + 1)))
    return np.array(v), faces


def test_automatic_binding_refuses_when_poses_are_ambiguous():
    vertices, faces = uv_sphere()
    rng = np.random.default_rng(1)
    d = rng.normal(size=(30, 3))
    d[:, 1] = -np.abs(d[:, 1]) - 1
    markers = d / np.linalg.norm(d, axis=1, keepdims=True) * 100 + rng.normal(size=(30, 3)) * 0.2
    with pytest.raises(FacecapError, match=r"automatic binding is ambiguous: two poses \d+ deg apart fit the markers "
                                           r"almost equally well .*give at least three landmarks"):
        bind_nearest(vertices, faces, [f"m{i}" for i in range(30)], markers, marker_mm_per_unit=1.0)


def test_bad_landmarks_and_too_few_markers_are_refused(face):
    vertices, tris, names, truth, vertex, _ = face
    markers, _ = actor_take(truth, 3)
    with pytest.raises(FacecapError, match="need at least 3 marker -> vertex pairs; got 2"):
        bind_nearest(vertices, tris, names, markers, landmarks={"chin_C": vertex["chin_C"], "nose_tip_C": 1},
                     marker_mm_per_unit=1.0)
    line = {names[0]: 0, names[1]: 1, names[2]: 2}
    collinear = markers.copy()
    collinear[:3] = [[0, 0, 0], [10, 0, 0], [20, 0, 0]]
    with pytest.raises(FacecapError, match="landmarks: .*collinear"):
        bind_nearest(vertices, tris, names, collinear, landmarks=line, marker_mm_per_unit=1.0)
    with pytest.raises(FacecapError, match="landmark 'nope' is not a marker of the take"):
        bind_nearest(vertices, tris, names, markers, landmarks={"nope": 1, "chin_C": 2, "nose_tip_C": 3},
                     marker_mm_per_unit=1.0)
    with pytest.raises(FacecapError, match="at least 4 markers with a neutral position; got 3"):
        bind_nearest(vertices, tris, names[:3], markers[:3], marker_mm_per_unit=1.0)


def test_map_binding_to_vertices_groups_and_points(face):
    vertices, tris, names, truth, vertex, deltas = face
    groups = {"grp_chin": ([vertex["chin_C"], vertex["chin_L"]], [1.0, 1.0])}
    point = truth[names.index("nose_tip_C")]
    targets = {"chin_C": str(vertex["chin_C"]), "chin_L": "grp_chin", "nose_tip_C": f"{point[0]},{point[1]},{point[2]}",
               "brow_inner_L": (0.0, -5.0, 0.0)}
    b = bind_map(vertices, tris, names, targets, vertex_groups=groups)
    at = {n: i for i, n in enumerate(names)}
    assert b.bound[at["chin_C"]] and b.distance_mm[at["chin_C"]] == 0.0
    np.testing.assert_allclose(b.points(vertices)[at["chin_C"]], vertices[vertex["chin_C"]], atol=1e-15)
    np.testing.assert_allclose(b.points(vertices)[at["nose_tip_C"]], point, atol=1e-9)
    mid = (vertices[vertex["chin_C"]] + vertices[vertex["chin_L"]]) / 2
    assert b.distance_mm[at["chin_L"]] == pytest.approx(np.linalg.norm(b.points(vertices)[at["chin_L"]] - mid) * 1000)
    assert not b.bound[at["brow_inner_L"]]  # 5 m away: unbound, with a warning
    assert any("farther than 8 mm" in n and "brow_inner_L" in n for n in b.notes)
    assert any(f"{len(names) - 4} marker(s) not in the map stay unbound" in n for n in b.notes)
    sampled = sample_basis(b, deltas)
    assert sampled.shape == (3, len(names), 3)
    np.testing.assert_allclose(sampled[:, at["chin_C"]], deltas[:, vertex["chin_C"]], atol=1e-15)
    assert np.isnan(sampled[:, ~b.bound]).all()
    with pytest.raises(FacecapError, match="no vertex group 'missing' on the character"):
        bind_map(vertices, tris, names, {"chin_C": "missing"}, vertex_groups=groups)
    with pytest.raises(FacecapError, match="vertex 999999 does not exist"):
        bind_map(vertices, tris, names, {"chin_C": 999999})
    with pytest.raises(FacecapError, match=r"binding map names marker\(s\) \['nope'\]"):
        bind_map(vertices, tris, names, {"nope": 1})


def test_sampled_basis_interpolates_the_mesh_deltas(face):
    vertices, tris, names, truth, _, deltas = face
    markers, _ = actor_take(truth, 7)
    b = bind_nearest(vertices, tris, names, markers, landmarks={n: truth[names.index(n)] for n in
                                                                 ("nose_tip_C", "chin_C", "brow_inner_L", "brow_inner_R")},
                     marker_mm_per_unit=1.0)
    moved = b.points(vertices + deltas[0])  # the jawOpen shape applied to the mesh
    np.testing.assert_allclose(b.sample(deltas)[0], moved - b.points(vertices), atol=1e-12)
    assert parse_target("12") == 12 and parse_target("mouth grp") == "mouth grp"
    np.testing.assert_array_equal(parse_target("(1, 2.5, -3)"), [1.0, 2.5, -3.0])


@skip_without(FACIAL_SING)
def test_real_facial_capture_binds_to_the_sample_character(face):
    """c3dorg_29_Facial-Sing (NaturalPoint, 38 markers, mm) onto the sample character, both ways."""
    from facecap.solvers.io import import_markers

    vertices, tris, _, _, vertex, _ = face
    take = import_markers(FACIAL_SING).markers
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Unlabeled1 is a gap over the whole first second
        neutral = np.nanmedian(take.positions[:100], axis=0)  # the first second
    landmarks = {"section7-2": vertex["nose_tip_C"], "section14-2": vertex["chin_C"],
                 "section11-1": vertex["mouth_corner_L"], "section12-1": vertex["mouth_corner_R"],
                 "section1-1": vertex["brow_inner_L"], "section2-1": vertex["brow_inner_R"]}
    results = {}
    for how, marks in (("automatic", None), ("landmarks", landmarks)):
        b = bind_nearest(vertices, tris, take.names, neutral, landmarks=marks, marker_mm_per_unit=1.0)
        results[how] = b
        assert int(b.bound.sum()) >= 33  # of 37 with a neutral position; head-band markers stay off
        assert np.median(b.distance_mm[b.bound]) < 2.0
        assert not b.bound[take.names.index("Unlabeled1")]  # no neutral position
        for n in ("root-1", "root-2"):  # ~24 mm off the face (a head band)
            assert not b.bound[take.names.index(n)]
    assert results["automatic"].similarity.scale == pytest.approx(results["landmarks"].similarity.scale, rel=0.02)



def test_closest_points_are_those_of_every_triangle_tested(face):
    """The k-d tree's queries against testing every triangle: the exact query finds the same closest point
    for points on, near and far from the face; the k nearest centroids are the k a full search finds."""
    vertices, tris, _, truth, _, _ = face
    surface = make_surface(vertices, tris)
    rng = np.random.default_rng(0)
    points = np.concatenate([truth + rng.normal(size=truth.shape) * s for s in (0.0005, 0.005, 0.05, 0.5)])
    T = surface.n_triangles
    a, b, c = surface.corners(np.tile(np.arange(T), len(points)))
    q, _ = closest_on_triangles(np.repeat(points, T, axis=0), a, b, c)
    every = np.linalg.norm(np.repeat(points, T, axis=0) - q, axis=1).reshape(len(points), T).min(axis=1)
    _, _, _, dist = closest_points(surface, points)
    assert np.allclose(dist, every, rtol=0, atol=1e-12)
    d2 = np.sum((points[:, None] - surface.centroids[None]) ** 2, axis=-1)
    brute = np.argsort(d2, axis=1)[:, :16]
    near = nearest_triangles(surface, points, 16)
    assert all(set(x) == set(y) for x, y in zip(near, brute))
    tri, _, _, dist = closest_points(surface, np.vstack([points[:1], [np.nan, 0.0, 0.0]]))
    assert tri[1] == -1 and np.isnan(dist[1]) and dist[0] == pytest.approx(every[0])  # no position: no point
