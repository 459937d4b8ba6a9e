"""The review page's renders and the sidebar's *Export Review Report*: the character is rendered in the
pose the solve gave each picked frame, the markers drawn beside it land on the face where the solve put
them, and the user's scene is left exactly as it was."""

import dataclasses
import json
import re
import subprocess
import sys
import time
from pathlib import Path

import bpy
import numpy as np
import pytest
from png_pixels import png_pixels
from render_child import in_child

from facecap.facecap_addon.render import review as rv
from facecap.facecap_addon.headless.demo import SAMPLE_CONFIG
from facecap.facecap_addon.headless.headless import run_take
from facecap.facecap_addon.scene.scene_binding import bound_basis
from facecap.solvers.config import load_take_config
from facecap.solvers.tools.report import marker_geometry, pick_frames

SAMPLES = Path(__file__).resolve().parents[2] / "sample_blends"
#: Blender aborts (SIGABRT) when it finds no OpenGL context for Workbench (no Mesa EGL); the forked
#: render then reports it and the tests below that need pixels cannot run.
WHITE = 250


def _pixels(png, tmp_path, name="tile.png"):
    """(H, W, 3) 0..255 floats of PNG bytes, top row first."""
    path = tmp_path / name
    path.write_bytes(png)
    return png_pixels(path)


@pytest.fixture(scope="module")
def solved(tmp_path_factory):
    """The sample take solved headless (weights only): the character stays open in this process."""
    out = tmp_path_factory.mktemp("review")
    config = dataclasses.replace(load_take_config(SAMPLE_CONFIG), output_blend=None, output_report=None,
                                 output_weights=out / "w.csv")
    result, _ = run_take(config, quiet=True)
    return result, config


def _counts():
    return {kind: len(getattr(bpy.data, kind)) for kind in ("scenes", "objects", "meshes", "cameras", "worlds",
                                                             "shape_keys", "actions", "images")}


#: The first review of a fresh headless process (nothing rendered in it yet): run in its own Python, as
#: other tests of this session render in-process (Workbench footage, docs pictures) and from then on a
#: forked child could not render.
FRESH_PROCESS_REVIEW = """
import dataclasses, json, sys
import bpy
from facecap.facecap_addon.render import review as rv
from facecap.facecap_addon.headless.demo import SAMPLE_CONFIG
from facecap.facecap_addon.headless.headless import run_take
from facecap.solvers.config import load_take_config
from pathlib import Path
config = dataclasses.replace(load_take_config(SAMPLE_CONFIG), output_blend=None, output_report=None,
                             output_weights=Path(sys.argv[1]))
result, _ = run_take(config, quiet=True)
kinds = ("scenes", "objects", "meshes", "cameras", "worlds", "shape_keys", "actions", "images")
counts = lambda: {kind: len(getattr(bpy.data, kind)) for kind in kinds}
rendered_before, before = rv._state["rendered_here"], counts()
review = rv.build_review(bpy.data.objects["Face"], result, config.settings, take="sample", character="c", fps=60.0)
print("REVIEW " + json.dumps({
    "rendered_before": rendered_before, "rendered_after": rv._state["rendered_here"],
    "note": review.sheet_note, "tiles": len(review.sheet.tiles) if review.sheet else 0,
    "render_s": review.timings.get("render", 0), "same_scene": counts() == before,
    "geometry": review.geometry is not None and list(review.geometry.names) == list(result.marker_names)}))
"""


def test_build_review_renders_in_a_forked_child_and_leaves_the_scene(tmp_path):
    """A headless process that never rendered renders the contact sheet in a forked child (an abort there
    cannot end the run) and its scene is left exactly as it was."""
    proc = subprocess.run([sys.executable, "-c", FRESH_PROCESS_REVIEW, str(tmp_path / "w.csv")],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    found = json.loads(proc.stdout.split("REVIEW ", 1)[1].splitlines()[0])
    assert not found["rendered_before"] and found["tiles"] >= 6, found["note"]
    assert found["render_s"] > 0 and found["geometry"] and found["same_scene"]
    assert not found["rendered_after"], "the renders ran in a child"


def test_a_process_that_rendered_renders_in_process(solved):
    """After any render in this process (Workbench footage, docs pictures, an earlier review) the sheet is
    rendered here: a forked child's copy of the OpenGL context would hang. (Run in a child of its own: the
    pytest process never renders, ``render_child``.)"""
    result, config = solved

    def review():
        rv._state["rendered_here"] = True  # the child's copy of the flag
        built = rv.build_review(bpy.data.objects["Face"], result, config.settings, take="sample", character="c",
                                fps=60.0)
        return built.sheet is not None and len(built.sheet.tiles), built.sheet_note

    tiles, note = in_child(review, label="the review rendered in-process")
    assert tiles >= 6, note


def _aborts(marker=None):
    """A render_sheet that dies as Blender does without OpenGL: always, or (given a ``marker`` path) only the
    first time it is called in any process."""
    real = rv.render_sheet

    def render(*args, **kwargs):
        import os

        if marker is None or not marker.exists():
            if marker is not None:
                marker.touch()
            os.write(2, b"EGL Error (0x3009): EGL_BAD_MATCH\n")  # Blender's last words without OpenGL
            os.abort()
        return real(*args, **kwargs)

    return render


def test_a_failed_render_is_a_note_not_an_error(solved, monkeypatch):
    result, config = solved
    monkeypatch.setattr(rv, "render_sheet", _aborts())
    monkeypatch.setitem(rv._state, "rendered_here", False)  # fork, as a headless run that never rendered does
    review = rv.build_review(bpy.data.objects["Face"], result, config.settings, take="sample", character="c")
    assert review.sheet is None and review.sheet_note.startswith(
        "Blender stopped while rendering (2 tries, exit -6, -6; it printed last: EGL Error (0x3009): EGL_BAD_MATCH)")
    assert review.geometry is not None  # the binding plot does not need renders


def test_a_render_that_died_once_is_tried_again(solved, monkeypatch, tmp_path):
    """Software OpenGL has aborted once in a long run that rendered before and after: the contact sheet gets a
    second child."""
    result, config = solved
    monkeypatch.setattr(rv, "render_sheet", _aborts(tmp_path / "died"))
    monkeypatch.setitem(rv._state, "rendered_here", False)
    review = rv.build_review(bpy.data.objects["Face"], result, config.settings, take="sample", character="c")
    assert (tmp_path / "died").exists(), "the first child died"
    assert review.sheet is not None and len(review.sheet.tiles) >= 6, review.sheet_note


def test_a_render_that_hung_once_is_tried_again(solved, monkeypatch, tmp_path):
    """A fork of a multi-threaded process can deadlock (a child hung once in CI, Python 3.13): a child stopped at the
    timeout gets a second; two that hang are a note."""
    result, config = solved
    marker = tmp_path / "hung"
    real = rv.render_sheet

    def hangs_once(*args, **kwargs):
        if not marker.exists():
            marker.touch()
            time.sleep(600)
        return real(*args, **kwargs)

    monkeypatch.setattr(rv, "render_sheet", hangs_once)
    monkeypatch.setattr(rv, "RENDER_TIMEOUT", 20.0)
    monkeypatch.setitem(rv._state, "rendered_here", False)
    review = rv.build_review(bpy.data.objects["Face"], result, config.settings, take="sample", character="c")
    assert marker.exists() and review.sheet is not None and len(review.sheet.tiles) >= 6, review.sheet_note
    monkeypatch.setattr(rv, "render_sheet", lambda *a, **k: time.sleep(600))
    monkeypatch.setattr(rv, "RENDER_TIMEOUT", 1.0)
    review = rv.build_review(bpy.data.objects["Face"], result, config.settings, take="sample", character="c")
    assert review.sheet is None and review.sheet_note == "rendering took longer than 1 s and was stopped (2 tries)"


def test_tiles_show_the_solved_pose_with_the_markers_on_the_face(solved, tmp_path):
    in_child(lambda: _tiles_show_the_solved_pose(solved, tmp_path), label="the contact sheet")


def _tiles_show_the_solved_pose(solved, tmp_path):
    result, config = solved
    obj = bpy.data.objects["Face"]
    key = obj.data.shape_keys
    bpy.context.view_layer.update()  # the keyed solve poses the face at the current frame (as any redraw would)
    before, values = _counts(), [b.value for b in key.key_blocks]
    geometry, why = marker_geometry(result, bound_basis(obj, result.stabilise.markers, config.settings), config.settings)
    assert why == ""
    picks = pick_frames(result, fps=60)
    sheet = rv.render_sheet(obj, result, geometry, picks)
    assert _counts() == before and [b.value for b in key.key_blocks] == values, "the user's scene is untouched"
    assert len(sheet.tiles) == len(picks) >= 6 and sheet.binding is not None
    neutral = _pixels(sheet.binding.png, tmp_path, "neutral.png")
    for tile, (row, kind, _) in zip(sheet.tiles, picks):
        px = _pixels(tile.png, tmp_path)
        assert px.shape == (rv.TILE_HEIGHT, round(rv.TILE_HEIGHT * rv.ASPECT), 3)
        assert 0.2 < float((px.min(axis=2) < WHITE).mean()) < 0.8, "the face fills the tile, with room around it"
        # the character's bound points, projected, land on the face (not on the white background)
        inside = np.all((tile.model >= 0) & (tile.model < [px.shape[1], px.shape[0]]), axis=1)
        assert inside.all()
        cols, rows_ = tile.model[:, 0].astype(int), tile.model[:, 1].astype(int)
        assert (px[rows_, cols].min(axis=1) < WHITE).mean() > 0.95
        # the distances drawn are the solve's per-marker residual at that frame, in the character's mm: the
        # default solve fits in the actor's space (here the character's shapes taken as the actor's)
        scale = result.alignment.scale
        np.testing.assert_allclose(tile.distance_mm, result.frame_marker_residual[row] * 1e3 * scale, rtol=1e-6,
                                   atol=1e-9, equal_nan=True)
        assert tile.frame == result.frames[row] and tile.kind == kind
        if kind == "peak":  # an expression at its peak is not the neutral face
            assert np.abs(px - neutral).mean() > 0.3
    # sub-millimetre errors: the take's markers sit within a few pixels of the bound points
    gap = np.linalg.norm(sheet.tiles[0].captured - sheet.tiles[0].model, axis=1)
    assert np.nanmedian(gap) < 3.0


def test_without_bound_markers_the_whole_face_is_rendered_alone(solved, tmp_path):
    in_child(lambda: _whole_face_alone(solved, tmp_path), label="the contact sheet without markers")


def _whole_face_alone(solved, tmp_path):
    result, _ = solved
    picks = pick_frames(result, worst=0, peaks=2)
    sheet = rv.render_sheet(bpy.data.objects["Face"], result, None, picks)
    assert sheet.binding is None and sheet.marker_names == () and len(sheet.tiles) == 2
    for tile in sheet.tiles:
        assert tile.captured is None and tile.kind == "peak"
        px = _pixels(tile.png, tmp_path)
        assert 0.1 < float((px.min(axis=2) < WHITE).mean()) < 0.8


def test_export_review_report_from_the_sidebar(tmp_path):
    bpy.ops.wm.open_mainfile(filepath=str(SAMPLES / "character.blend"))
    assert bpy.ops.facecap.import_markers(filepath=str(SAMPLES / "sample_take.csv"), units="mm", fps=60.0) == {"FINISHED"}
    s = bpy.context.scene.facecap
    s.target = bpy.data.objects["Face"]
    stable = {m["name"] for m in json.loads((SAMPLES / "marker_layout.json").read_text())["markers"] if m["stable"]}
    for item in s.markers:
        item.stable = item.name in stable
    assert bpy.ops.facecap.set_neutral(first=1, last=50) == {"FINISHED"}
    before = _counts()
    out = tmp_path / "review.html"
    truth = SAMPLES / "sample_take_weights.csv"
    assert bpy.ops.facecap.export_review(filepath=str(out), truth_path=str(truth)) == {"FINISHED"}
    assert _counts() == before, "exporting keys nothing and leaves no data behind"
    html = out.read_text(encoding="utf-8")
    assert len(re.findall(r'<img id="tile-\d+"', html)) >= 6 and 'id="tile-binding"' in html
    assert "weights RMSE 0.0" in html  # the truth overlay's summary (the sample solves to RMSE ~0.018)
    assert "character.blend: Face" in html
    with pytest.raises(RuntimeError, match="the review page is the same file as the truth weights"):
        bpy.ops.facecap.export_review(filepath=str(truth), truth_path=str(truth))
