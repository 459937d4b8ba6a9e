"""[binding] in take configs, the marker,target map file, markers left out before the take is prepared,
and stored bindings (records) -- everything about binding except its accuracy (test_binding_accuracy.py)."""

import numpy as np
import pytest
from synthetic_face import make_basis

from facecap.solvers import ConfigError, InputFileError, load_take_config
from facecap.solvers.character.binding_map import BindingSettings, read_binding_map
from facecap.solvers.character.mesh import CharacterMesh, binding_sampling, group_sampling, sampled_basis
from facecap.solvers.config.paths import check_outputs, take_inputs
from facecap.solvers.errors import FacecapError
from facecap.solvers.markers import MarkerSet
from facecap.solvers.pipeline import RetargetSettings, retarget
from facecap.solvers.pipeline.binding import bind_character, binding_record, from_record
from facecap.solvers.tools.synthetic.synth import synthesize_take

BASE = """
[target]
object = "Face"
[source]
markers = "t1.csv"
[stabilise]
markers = ["a", "b", "c"]
[neutral]
frames = [1, 30]
[output]
weights = "out/w.csv"
"""


def write(tmp_path, text, name="take.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_binding_modes_are_read(tmp_path):
    assert load_take_config(write(tmp_path, BASE)).binding == BindingSettings()
    old = load_take_config(write(tmp_path, BASE + "[binding]\nvertex_groups = true\n"))
    assert old.binding.mode == "vertex_groups" and old.bind_vertex_groups
    (tmp_path / "map.csv").write_text("marker,target\na,grp\n")
    cfg = load_take_config(write(tmp_path, BASE + '[binding]\nmode = "map"\nmap = "map.csv"\nmax_distance_mm = 3\n'))
    assert cfg.binding.mode == "map" and cfg.binding.map_path == (tmp_path / "map.csv").resolve()
    assert cfg.binding.max_distance_mm == 3.0 and cfg.binding.targets() == {"a": "grp"}
    assert take_inputs(cfg)["[binding.map]"] == (tmp_path / "map.csv").resolve()
    near = load_take_config(write(tmp_path, BASE + '[binding]\nmode = "nearest"\n'
                                  '[binding.landmarks]\na = "nose_tip"\nb = 120\nc = "0.1, 0.2, 0.3"\n'))
    assert near.binding.landmarks == (("a", "nose_tip"), ("b", "120"), ("c", "0.1, 0.2, 0.3"))
    assert near.binding.by_position and not near.bind_vertex_groups


@pytest.mark.parametrize("extra, message", [
    ('mode = "closest"', r"\[binding.mode\] expected one of vertex_groups, map, nearest; got 'closest'"),
    ("vertex_groups = false", r"\[binding.vertex_groups\] false needs a binding mode"),
    ('vertex_groups = true\nmode = "nearest"', r"\[binding.vertex_groups\] vertex_groups = true contradicts mode"),
    ('mode = "map"', r"\[binding.map\] mode = \"map\" needs map ="),
    ('mode = "map"\nmap = "absent.csv"', r"\[binding.map\] file not found: .*absent.csv"),
    ('map = "map.csv"', r"\[binding.map\] a map is only read with mode = \"map\""),
    ('mode = "nearest"\nlandmarks = { a = "x", b = "y" }', r"\[binding.landmarks\] expected at least 3 .* got 2"),
    ('mode = "nearest"\nlandmarks = { a = "x", b = "y", c = 1.5 }', r"\[binding.landmarks.c\] expected a vertex group"),
    ('mode = "nearest"\nlandmarks = { a = "x", b = "y", c = -2 }', r"\[binding.landmarks.c\] a vertex index is >= 0"),
    ('landmarks = { a = "x", b = "y", c = "z" }', r"\[binding.landmarks\] landmarks are only used with mode = \"nearest\""),
    ("max_distance_mm = 5", r"\[binding.max_distance_mm\] max_distance_mm applies to mode"),
    ('mode = "nearest"\nmax_distance_mm = 0', r"\[binding.max_distance_mm\] expected a number > 0"),
])
def test_binding_errors_name_the_key(tmp_path, extra, message):
    (tmp_path / "map.csv").write_text("a,grp\n")
    with pytest.raises(ConfigError, match=message):
        load_take_config(write(tmp_path, BASE + "[binding]\n" + extra + "\n"))


def test_the_map_is_an_input_no_output_may_overwrite(tmp_path):
    (tmp_path / "map.csv").write_text("a,grp\n")
    cfg = load_take_config(write(tmp_path, BASE.replace("out/w.csv", "map.csv")
                                 + '[binding]\nmode = "map"\nmap = "map.csv"\n'))
    with pytest.raises(ConfigError, match=r"\[output.weights\] is the same file as \[binding.map\]"):
        check_outputs(cfg)


def test_map_file_rows(tmp_path):
    path = tmp_path / "map.csv"
    path.write_text('# blenderFace -> sample character\nmarker,target\nA7,lip_upper_C\n\nB2,1234\n'
                    'C1,"0.03,-0.05,0.004"\nC2, -0.03 ,-0.05, 0.004\nD1,nose side grp\n')
    assert read_binding_map(path) == {"A7": "lip_upper_C", "B2": "1234", "C1": "0.03,-0.05,0.004",
                                      "C2": "-0.03,-0.05,0.004", "D1": "nose side grp"}


@pytest.mark.parametrize("text, message", [
    ("a,g\na,h\n", r"map.csv, line 2: marker 'a' is mapped twice"),
    ("a,g\nb\n", r"map.csv, line 2: expected marker,target or marker,x,y,z; got 1 cell"),
    ("a,1,2\n", r"map.csv, line 1: expected marker,target or marker,x,y,z; got 3 cell"),
    ("a,x,y,z\n", r"map.csv, line 1: marker 'a': x,y,z must be three numbers"),
    ("marker,target\n# nothing\n", r"map.csv: no marker,target rows"),
])
def test_map_file_errors_name_the_line(tmp_path, text, message):
    path = tmp_path / "map.csv"
    path.write_text(text)
    with pytest.raises(InputFileError, match=message):
        read_binding_map(path)
    with pytest.raises(InputFileError, match="file not found"):
        read_binding_map(tmp_path / "absent.csv")


@pytest.fixture(scope="module")
def take():
    basis, stable = make_basis()
    rng = np.random.default_rng(2)
    W = np.clip(rng.uniform(-0.5, 1.0, size=(200, basis.n_shapes)), 0, 1)
    W[:60] = 0
    synth = synthesize_take(basis, W, stable=stable, noise_sigma=0.0, gap_fraction=0.0)
    return basis, stable, W, synth.markers


def test_markers_without_a_neutral_or_a_binding_are_left_out_with_a_note(take):
    """A marker with no sample over the neutral frames used to stop the take; an unbound one is not
    prepared. Both are named; the solve of the others is unchanged."""
    basis, stable, W, markers = take
    settings = RetargetSettings(stable, (1, 50), regularisation=0.0, sparsity=0.0, head_smoothing=0.0,
                                smoothing=(0.0, 0.0))
    pos = markers.positions.copy()
    pos[:70, -1] = np.nan  # no sample in frames 1-50
    stray = pos[:, -2:-1] + 0.05  # a marker the character has no binding for
    gappy = MarkerSet(markers.names[:-1] + ("late",), markers.frames, pos, fps=markers.fps, units=markers.units)
    extra = MarkerSet(gappy.names + ("stray",), markers.frames, np.concatenate([pos, stray], axis=1),
                      fps=markers.fps, units=markers.units)
    r = retarget(extra, basis.subset_markers(basis.marker_names[:-1]), settings)
    assert any("no sample over the neutral frames and are left out: late (" in w for w in r.warnings), r.warnings
    assert any("neither bound on the character nor stable and are left out: stray (" in w for w in r.warnings)
    assert "late" not in r.marker_names and "stray" not in r.marker_names
    assert np.abs(r.weights - W).max() < 1e-6
    with pytest.raises(FacecapError, match=r"never visible there: \['" + stable[0]):  # a stable one is needed
        bad = markers.positions.copy()
        bad[:60, 0] = np.nan
        retarget(markers.with_positions(bad), basis, settings)


def _plane_mesh(n=12, size=0.1):
    """A bumpy grid (metres) with two shapes and a vertex group per interior vertex."""
    u, v = np.meshgrid(np.linspace(-size, size, n), np.linspace(-size, size, n))
    z = 0.01 * np.sin(8 * u) * np.cos(6 * v)
    vertices = np.stack([u.ravel(), v.ravel(), z.ravel()], axis=1)
    quads = [(i * n + j, i * n + j + 1, (i + 1) * n + j + 1, (i + 1) * n + j) for i in range(n - 1) for j in range(n - 1)]
    tris = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    deltas = np.stack([np.tile([0.0, 0.0, 0.004], (len(vertices), 1)) * u.ravel()[:, None] * 10,
                       np.tile([0.003, 0.0, 0.0], (len(vertices), 1)) * v.ravel()[:, None] * 10])
    groups = {f"g{k}": ([k, k + 1], [0.5, 0.5]) for k in range(n + 1, 2 * n - 2)}
    return CharacterMesh.from_arrays(vertices, tris, ("up", "side"), deltas, vertex_groups=groups, name="plane")


def test_map_binding_samples_the_same_points_as_vertex_groups_and_stores_a_record():
    mesh = _plane_mesh()
    names = tuple(mesh.vertex_groups)
    markers = MarkerSet(names, np.arange(1.0, 4.0), np.zeros((3, len(names), 3)), units="m")
    groups = bind_character(mesh, markers, None, BindingSettings())
    mapped = bind_character(mesh, markers, None, BindingSettings(mode="map", map=tuple((n, n) for n in names)))
    assert groups.mode == "vertex_groups" and groups.record is None and mapped.mode == "map"
    # each group's centroid is the midpoint of an edge: on the surface, so both sample the same point
    np.testing.assert_allclose(mapped.basis.neutral, groups.basis.neutral, atol=1e-12)
    np.testing.assert_allclose(mapped.basis.deltas, groups.basis.deltas, atol=1e-12)
    again = bind_character(mesh, markers, None, BindingSettings(mode="map"), record=mapped.record)
    np.testing.assert_array_equal(again.basis.deltas, mapped.basis.deltas)
    assert again.markers == mapped.markers and again.report()["bound"] == len(names)
    with pytest.raises(FacecapError, match="belongs to a mesh of 144 vertices; the character has 143"):
        from_record(mapped.record, 143)
    with pytest.raises(FacecapError, match="stored binding is damaged"):
        from_record({**mapped.record, "corners": [1, 2]}, 144)
    sampling, table, notes = from_record(mapped.record, 144, names + ("extra",))
    assert table["extra"] == (False, None) and "not in the stored binding: ['extra']" in notes[-1]


def test_vertex_group_binding_needs_three_groups_and_names_the_rest():
    mesh = _plane_mesh()
    names = ("g13", "g14", "nope")
    markers = MarkerSet(names, np.arange(1.0, 4.0), np.zeros((3, 3, 3)), units="m")
    with pytest.raises(FacecapError, match=r"only 2 of the take's 3 markers have a vertex group .* mode = \"nearest\""):
        bind_character(mesh, markers, None, BindingSettings())
    assert sampled_basis(mesh, group_sampling(mesh, ("g13", "g14", "g15"))).n_markers == 3
    with pytest.raises(FacecapError, match="only 1 marker"):
        sampled_basis(mesh, group_sampling(mesh, ("g13",)))


def test_binding_record_is_plain_data():
    mesh = _plane_mesh()
    names = ("g13", "g14", "g15", "far")
    markers = MarkerSet(names, np.arange(1.0, 4.0), np.zeros((3, 4, 3)), units="m")
    bound = bind_character(mesh, markers, None, BindingSettings(mode="map", map=(("g13", "g13"), ("g14", "14"),
                                                                                   ("g15", "0.0,0.0,0.0"),
                                                                                   ("far", "0,0,1"))))
    rec = bound.record
    assert rec["bound"] == [1, 1, 1, 0] and rec["distance_mm"][3] == -1.0 or rec["distance_mm"][3] > 900
    assert all(isinstance(x, (int, float)) for x in rec["corners"] + rec["barycentric"] + rec["distance_mm"])
    assert bound.markers["far"][0] is False and "far" in bound.report()["unbound"]
    sampling = binding_sampling(type("B", (), {"names": names, "triangles": np.array([0, 1, 2, -1]),
                                               "barycentric": np.eye(4, 3), "bound": np.array([1, 1, 1, 0], bool),
                                               "mesh_triangles": mesh.triangles})())
    assert set(sampling) == {"g13", "g14", "g15"}
    with pytest.raises(FacecapError, match="needs a Binding"):
        binding_record(object(), n_vertices=3)
