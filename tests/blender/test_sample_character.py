"""The committed sample character: geometry, 52 ARKit shape keys, symmetry, markers, determinism."""

import json
import re
from pathlib import Path

import bpy
import numpy as np
import pytest
from sample_geometry import geometry_module

SAMPLE_DIR = Path(__file__).resolve().parents[2] / "sample_blends"
BLEND = SAMPLE_DIR / "character.blend"
LAYOUT = SAMPLE_DIR / "marker_layout.json"

ARKIT = (
    "eyeBlinkLeft eyeLookDownLeft eyeLookInLeft eyeLookOutLeft eyeLookUpLeft eyeSquintLeft eyeWideLeft "
    "eyeBlinkRight eyeLookDownRight eyeLookInRight eyeLookOutRight eyeLookUpRight eyeSquintRight "
    "eyeWideRight jawForward jawLeft jawRight jawOpen mouthClose mouthFunnel mouthPucker mouthLeft "
    "mouthRight mouthSmileLeft mouthSmileRight mouthFrownLeft mouthFrownRight mouthDimpleLeft "
    "mouthDimpleRight mouthStretchLeft mouthStretchRight mouthRollLower mouthRollUpper mouthShrugLower "
    "mouthShrugUpper mouthPressLeft mouthPressRight mouthLowerDownLeft mouthLowerDownRight "
    "mouthUpperUpLeft mouthUpperUpRight browDownLeft browDownRight browInnerUp browOuterUpLeft "
    "browOuterUpRight cheekPuff cheekSquintLeft cheekSquintRight noseSneerLeft noseSneerRight tongueOut"
).split()
PAIRS = {"jawLeft": "jawRight", "mouthLeft": "mouthRight"}
FLIP = np.array([-1.0, 1.0, 1.0])


class Character:
    """Arrays read once from the saved .blend."""

    def __init__(self):
        bpy.ops.wm.open_mainfile(filepath=str(BLEND))
        obj = bpy.data.objects["Face"]
        mesh = obj.data
        self.object_type, self.mesh_name = obj.type, mesh.name
        nv = len(mesh.vertices)
        co = np.empty(nv * 3, dtype=np.float32)
        mesh.vertices.foreach_get("co", co)
        self.co = co.reshape(-1, 3).astype(np.float64)
        blocks = mesh.shape_keys.key_blocks
        self.key_names = [kb.name for kb in blocks]
        self.use_relative = mesh.shape_keys.use_relative
        self.relative_to = {kb.name: kb.relative_key.name for kb in blocks}
        self.slider = {kb.name: (kb.slider_min, kb.slider_max) for kb in blocks}
        basis = np.empty(nv * 3, dtype=np.float32)
        blocks["Basis"].data.foreach_get("co", basis)
        self.basis = basis.reshape(-1, 3).astype(np.float64)
        self.deltas = {}
        for kb in blocks[1:]:
            buf = np.empty(nv * 3, dtype=np.float32)
            kb.data.foreach_get("co", buf)
            self.deltas[kb.name] = buf.reshape(-1, 3).astype(np.float64) - self.basis
        names = [g.name for g in obj.vertex_groups]
        self.groups = {name: ([], []) for name in names}
        for v in mesh.vertices:
            for ge in v.groups:
                ids, ws = self.groups[names[ge.group]]
                ids.append(v.index)
                ws.append(ge.weight)
        self.group_names = names

    def centroid(self, name, positions=None):
        ids, ws = self.groups[name]
        p = self.basis if positions is None else positions
        return np.average(p[ids], axis=0, weights=ws)


@pytest.fixture(scope="module")
def char():
    return Character()


@pytest.fixture(scope="module")
def layout():
    return json.loads(LAYOUT.read_text())


@pytest.fixture(scope="module")
def mirror(char):
    """Index of the X-mirror of every vertex (nearest neighbour of the flipped position)."""
    p = char.basis
    flipped = p * FLIP
    out = np.empty(len(p), dtype=int)
    dist = np.empty(len(p))
    for s in range(0, len(p), 512):
        d2 = ((flipped[s:s + 512, None, :] - p[None, :, :]) ** 2).sum(axis=2)
        out[s:s + 512] = d2.argmin(axis=1)
        dist[s:s + 512] = np.sqrt(d2.min(axis=1))
    assert dist.max() < 1e-6, f"vertex without a mirror partner: {dist.max():.3g} m"
    return out


def test_one_face_mesh_with_enough_vertices(char):
    assert char.object_type == "MESH"
    assert char.mesh_name == "Face"
    assert len(char.basis) >= 2000
    assert np.array_equal(char.co, char.basis)


def test_size_orientation_and_nose_tip(char):
    lo, hi = char.basis.min(axis=0), char.basis.max(axis=0)
    assert 0.18 <= hi[2] - lo[2] <= 0.26
    assert np.all(np.abs(0.5 * (lo + hi)) < 0.03), "centred near the origin"
    tip = int(np.argmin(char.basis[:, 1]))
    assert abs(char.basis[tip, 0]) < 1e-6
    assert tip in char.groups["nose_tip_C"][0]
    # the face is at -Y: the eyes and mouth are in front of the head centre
    for name in ("eyelid_upper_L", "lip_upper_C", "chin_C"):
        assert char.centroid(name)[1] < -0.05


def test_shape_key_names_and_sliders(char):
    assert char.key_names[0] == "Basis"
    assert sorted(char.key_names[1:]) == sorted(ARKIT)
    assert len(char.key_names) == len(set(char.key_names)) == 53
    assert char.use_relative
    for name in ARKIT:
        assert char.relative_to[name] == "Basis"
        assert char.slider[name] == pytest.approx((0.0, 1.0))


def test_mirror_symmetry(char, mirror):
    p = char.basis
    assert np.array_equal(mirror[mirror], np.arange(len(p)))
    centre = mirror == np.arange(len(p))
    assert np.all(p[centre, 0] == 0.0)
    for name, d in char.deltas.items():
        if name.endswith("Left") and name not in PAIRS:
            other = name[:-4] + "Right"
        elif name in PAIRS:
            other = PAIRS[name]
        elif name.endswith("Right") or name in PAIRS.values():
            continue
        else:
            other = name
        np.testing.assert_allclose(char.deltas[other], d[mirror] * FLIP, atol=1e-6, err_msg=name)


def test_every_key_moves_locally(char):
    n = len(char.basis)
    for name, d in char.deltas.items():
        mag = np.linalg.norm(d, axis=1)
        small_ok = name.startswith("eyeLook") or name == "tongueOut"
        assert mag.max() >= (0.0005 if small_ok else 0.001), name
        assert (mag > 1e-4).sum() < 0.6 * n, f"{name} is not localised"
        assert mag.max() < 0.05, f"{name} moves a vertex by {mag.max():.3f} m"


def test_jaw_open_drops_the_chin_only(char):
    d = char.deltas["jawOpen"]
    chin = char.centroid("chin_C", char.basis + d) - char.centroid("chin_C")
    assert chin[2] <= -0.01
    forehead = char.basis[:, 2] > 0.05
    assert np.abs(d[forehead]).max() == 0.0
    assert np.abs(d[char.groups["lip_upper_C"][0]]).max() < 1e-4


def test_blink_left_closes_the_left_upper_lid(char):
    d = char.deltas["eyeBlinkLeft"]
    lid = char.centroid("eyelid_upper_L", char.basis + d) - char.centroid("eyelid_upper_L")
    assert lid[2] < -0.003
    assert np.abs(d[char.basis[:, 0] < 0.0]).max() == 0.0
    # at full blink the upper lid edge reaches the lower lid edge
    topo = geometry_module().build_character().topology
    closed = char.basis[topo.upper_edge] + d[topo.upper_edge]
    assert np.abs(closed - char.basis[topo.lower_edge]).max() < 0.0005
    assert np.all(d[topo.upper_edge, 2] < 0.0) and d[topo.upper_edge, 2].min() < -0.005


def test_smile_left_raises_the_left_corner(char):
    d = char.deltas["mouthSmileLeft"]
    move = char.centroid("mouth_corner_L", char.basis + d) - char.centroid("mouth_corner_L")
    assert move[2] > 0.002 and move[0] > 0.0
    assert np.abs(d[char.groups["mouth_corner_R"][0]]).max() == 0.0


def test_marker_groups_match_layout(char, layout):
    assert layout["object"] == "Face"
    names = [m["name"] for m in layout["markers"]]
    assert len(names) == len(set(names)) >= 50
    assert set(names) == set(char.group_names)
    for m in layout["markers"]:
        assert re.fullmatch(r"[a-z][a-z0-9_]*_[LRC]", m["name"]), m["name"]
        assert m["region"] in ("upper", "lower", "head")
        assert m["stable"] == m["name"].startswith("head_") == (m["region"] == "head")
        ids, ws = char.groups[m["name"]]
        assert 1 <= len(ids) <= 7
        assert sum(ws) == pytest.approx(1.0, abs=1e-3)
        if m["name"].endswith("_L"):
            assert char.centroid(m["name"])[0] > 0.0
        elif m["name"].endswith("_R"):
            assert char.centroid(m["name"])[0] < 0.0
        else:
            assert abs(char.centroid(m["name"])[0]) < 1e-6


def test_head_markers_never_move(char):
    head = [n for n in char.group_names if n.startswith("head_")]
    assert len(head) >= 6
    for name in head:
        ids = char.groups[name][0]
        worst = max(np.abs(d[ids]).max() for d in char.deltas.values())
        assert worst < 1e-9, name
    pts = np.array([char.centroid(n) for n in head])
    sv = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
    assert sv[1] > 1e-4, "head markers are (nearly) collinear"


def _marker_basis(char):
    names = [n for n in ARKIT if not n.startswith("eyeLook") and n != "tongueOut"]
    rest = np.array([char.centroid(g) for g in char.group_names])
    cols = []
    for name in names:
        moved = char.basis + char.deltas[name]
        cols.append((np.array([char.centroid(g, moved) for g in char.group_names]) - rest).ravel())
    return names, np.stack(cols, axis=1)


def test_marker_basis_is_well_posed(char):
    names, basis = _marker_basis(char)
    unit = basis / np.linalg.norm(basis, axis=0)
    cos = unit.T @ unit
    np.fill_diagonal(cos, -1.0)
    i, j = np.unravel_index(np.argmax(cos), cos.shape)
    assert cos[i, j] < 0.95, f"{names[i]} and {names[j]} look alike (cos {cos[i, j]:.3f})"
    assert np.linalg.cond(basis) < 1e4


def test_geometry_is_deterministic():
    cg = geometry_module()
    a, b = cg.build_character(), cg.build_character()
    assert np.array_equal(a.vertices, b.vertices)
    assert a.faces == b.faces
    assert np.array_equal(a.mirror, b.mirror)
    assert list(a.shape_keys) == list(b.shape_keys) == ARKIT
    for name in ARKIT:
        assert np.array_equal(a.shape_keys[name], b.shape_keys[name])
    assert a.markers == b.markers


def test_blend_matches_the_generator(char):
    geo = geometry_module().build_character()
    np.testing.assert_allclose(char.basis, geo.vertices, atol=1e-7)
    for name in ARKIT:
        np.testing.assert_allclose(char.deltas[name], geo.shape_keys[name], atol=1e-6, err_msg=name)


def test_blend_is_saved_by_the_oldest_supported_blender():
    """Saved by 4.2 so it opens in 4.2-5.0 (a 5.0 file has a new header that 4.2 cannot read)."""
    import zstandard  # a dependency of the bpy wheel; the sample is saved compressed

    with open(BLEND, "rb") as fh:
        header = zstandard.ZstdDecompressor().stream_reader(fh).read(12)
    assert header == b"BLENDER-v402", f"{BLEND.name} was saved by {header!r}; regenerate it with bpy 4.2 " \
        "(see sample_blends/generate_character.py)"
