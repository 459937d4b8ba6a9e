"""Automatic binding never silently wrong: a pose that ran out of scale (wrong units) or that puts the markers on
the back of the head is refused, naming the landmarks that would settle it."""

import numpy as np
import pytest
from sample_geometry import geometry_module

from facecap.solvers.character.binding import bind_nearest, check_automatic_pose
from facecap.solvers.character.surface import make_surface, triangulate
from facecap.solvers.errors import FacecapError
from facecap.solvers.transforms import Similarity


@pytest.fixture(scope="module")
def head():
    g = geometry_module().build_character()
    names = [m.name for m in g.markers]
    centroids = np.array([(np.asarray(m.weights)[:, None] * g.vertices[list(m.vertices)]).sum(0) / sum(m.weights)
                          for m in g.markers])
    return g.vertices, triangulate(g.faces), names, centroids


def test_the_face_binds(head):
    vertices, tris, names, markers = head
    b = bind_nearest(vertices, tris, names, markers * 1000.0, marker_mm_per_unit=1.0)
    assert b.bound.sum() >= 60 and abs(b.similarity.scale - 1e-3) < 2e-5


def test_markers_in_the_wrong_units_are_refused(head):
    vertices, tris, names, markers = head
    with pytest.raises(FacecapError, match=r"no pose that fits.*units.*nose tip, the chin"):
        bind_nearest(vertices, tris, names, markers * 3000.0, marker_mm_per_unit=1.0)  # mm read as 1/3 mm


def test_poses_at_the_scale_bound_or_on_the_back_of_the_head_are_refused(head):
    vertices, tris, names, markers = head
    surface = make_surface(vertices, tris)
    face = markers * 1000.0  # mm
    right = Similarity(1e-3, np.eye(3), np.zeros(3))
    check_automatic_pose(surface, right, face, 1e-3)  # the true pose passes
    turned = np.diag([-1.0, -1.0, 1.0])  # half a turn about the vertical: the markers on the back of the head
    centre = vertices.mean(axis=0)
    back = Similarity(1e-3, turned, centre - turned @ centre)
    with pytest.raises(FacecapError, match="back of the head.*nose tip, the chin"):
        check_automatic_pose(surface, back, face, 1e-3)
    at_bound = Similarity(1e-3 * 1.25 * 1.15, np.eye(3), np.zeros(3))
    with pytest.raises(FacecapError, match="at the end of the search"):
        check_automatic_pose(surface, at_bound, face, 1e-3)
