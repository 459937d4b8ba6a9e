"""The range-of-motion session in the sidebar: choose a sheet, *Find Poses* marks the ROM take's holds on the
timeline (near their true middles; the user's own markers kept), a dragged marker moves the hold measured, *Save
Performer Profile* writes a profile (by the output policy) that makes a later solve of the same actor better than
knowing nothing.

The ROM take is the realism benchmark's: an ICT actor (dense layout, the sample character's marker names)
performing facecap-24 imperfectly with its own head motion and noise, imported as marker empties or read from a
CSV; the sample character (ARKit shape keys) is the target. No human template is installed here, so the poses are
named against the character's shapes, the prior the solve would use."""

import sys
from pathlib import Path

import bpy
import numpy as np
import pytest
from shared_data import SHARED, require

from scene_fixtures import draw_panel, modal_driver

from facecap.facecap_addon.scene import import_scene, rom_markers, scene_solve
from facecap.facecap_addon.scene.rom_scene import RomInBackground
from facecap.operators.rom import why_not
from facecap.solvers.character.basis import Basis
from facecap.solvers.character.face_model import load_ict
from facecap.solvers.io.csv import write_markers_csv
from facecap.solvers.rom import SHEETS
from facecap.solvers.tools.synthetic.realism.families import load_family
from facecap.solvers.tools.synthetic.realism.layouts import DENSE_HEAD
from facecap.solvers.tools.synthetic.realism.metrics import compare
from facecap.solvers.tools.synthetic.realism.rom import rom_session
from facecap.solvers.tools.synthetic.realism.scenario import make_draw
from facecap.solvers.tools.synthetic.realism.takes import REST, load_performances

sys.path.insert(0, str(Path(__file__).resolve().parent))

SAMPLES = Path(__file__).resolve().parents[2] / "sample_blends"
SHEET = "facecap-24"
#: The draw: seed 2 of the ICT family, a 5 s performance (its ROM session is about 60 s).
SEED, FRAMES = 2, 300


@pytest.fixture(scope="module")
def draw(tmp_path_factory):
    """The draw (its ROM sessions performed), and its facecap-24 ROM written as a CSV (millimetres)."""
    model = load_ict(require(SHARED / "data" / "ict-facekit"))
    family = load_family("ict", SHARED, model)
    performances = load_performances(require(SHARED / "data" / "realdata" / "llf"), model.shape_names)
    d = make_draw(family, performances, SEED, frames=FRAMES)
    csv = tmp_path_factory.mktemp("rom") / "rom_facecap24.csv"
    write_markers_csv(csv, d.roms[SHEET].markers)
    return d, csv


def _scene(draw, *, source="COLLECTION", csv=None):
    """The sample character with the draw's take imported as its take and the ROM take as the calibration source,
    the ROM sheet chosen (the sidebar after: import the take, import the ROM take, choose the sheet)."""
    bpy.ops.wm.open_mainfile(filepath=str(SAMPLES / "character.blend"))
    scene = bpy.context.scene
    take = import_scene.create_take(scene, draw.markers, "take")
    import_scene.remember_take(scene, draw.markers, Path("take.csv"), take)
    s = scene.facecap
    s.target = bpy.data.objects["Face"]
    s.strategy = "semantic"
    s.actor_template = "none"
    s.neutral_first, s.neutral_last = 1, REST
    if source == "COLLECTION":
        rom = draw.roms[SHEET].markers
        s.calib_collection = import_scene.create_take(scene, rom, "ROM", set_scene_range=False)
    else:
        s.calib_source, s.calib_path, s.calib_units = "FILE", str(csv), "mm"
    s.calib_neutral_first, s.calib_neutral_last = 1, 60  # the lead-in neutral (1.2-2 s)
    s.calib_sheet = SHEET
    return scene


def _rom_marks(scene):
    return {m.name[len(rom_markers.PREFIX):]: m.frame for m in rom_markers.rom_markers(scene)}


def test_the_rom_controls_say_why_they_are_greyed(draw):
    d, _ = draw
    scene = _scene(d)
    s = scene.facecap
    assert why_not(bpy.context) is None and bpy.ops.facecap.rom_find_poses.poll()
    s.calib_collection = None
    assert "ROM take" in why_not(bpy.context) and not bpy.ops.facecap.rom_save_profile.poll()
    s.calib_sheet = "NONE"
    assert "ROM sheet" in why_not(bpy.context) and not bpy.ops.facecap.rom_find_poses.poll()
    s.strategy = "geometric"
    assert "semantic" in why_not(bpy.context)
    # the sheet enum offers every built-in sheet, and the panel draws the ROM buttons once one is chosen
    assert {i.identifier for i in s.bl_rna.properties["calib_sheet"].enum_items} == {"NONE"} | set(SHEETS)
    s.strategy, s.calib_sheet = "semantic", SHEET
    calls = draw_panel("FACECAP_PT_solve").calls
    assert ("operator", "facecap.rom_find_poses") in calls and ("operator", "facecap.rom_save_profile") in calls
    assert ("template_list", "calib_poses") not in calls  # typed pose ranges only without a sheet
    s.calib_sheet = "NONE"
    assert ("template_list", "calib_poses") in draw_panel("FACECAP_PT_solve").calls


def test_find_poses_marks_each_hold_near_its_true_middle_and_keeps_other_markers(draw):
    d, _ = draw
    scene = _scene(d)
    scene.timeline_markers.new("slate", frame=3)  # the user's own marker
    scene.timeline_markers.new(rom_markers.PREFIX + "from an older run", frame=9000)
    assert bpy.ops.facecap.rom_find_poses() == {"FINISHED"}
    marks = _rom_marks(scene)
    assert "from an older run" not in marks and [m.frame for m in scene.timeline_markers if m.name == "slate"] == [3]
    session = d.roms[SHEET]
    labels = [SHEETS[SHEET][j].label for j in session.performed]
    off = np.array([abs(marks[label] - middle) if label in marks else np.inf
                    for label, middle in zip(labels, session.middles)])
    # the target: >= 95 % within 5 frames (measured on this draw: 24 of 24, at most 3 frames off)
    assert np.sum(off <= 5) >= 0.95 * len(labels), off
    # the next Find Poses replaces them, not adds
    assert bpy.ops.facecap.rom_find_poses() == {"FINISHED"}
    assert len(rom_markers.rom_markers(scene)) == len(marks)


def test_find_poses_runs_beside_the_interface_and_esc_leaves_the_markers(draw, monkeypatch):
    """From the sidebar: the ROM take measured on a thread while the status bar says what, Esc drops it with the
    timeline as it was; left to finish, the markers are placed as bpy.ops places them."""
    import threading
    from types import SimpleNamespace

    from facecap.facecap_addon.scene import rom_scene
    from facecap.operators.rom import FACECAP_OT_rom_find_poses

    d, _ = draw
    scene = _scene(d)
    old = scene.timeline_markers.new(rom_markers.PREFIX + "smile", frame=77)
    go = threading.Event()
    real = rom_scene.learn_from_rom_take
    monkeypatch.setattr(rom_scene, "learn_from_rom_take", lambda *a: go.wait(60) and real(*a))

    class Driver(modal_driver(FACECAP_OT_rom_find_poses)):
        untouched = FACECAP_OT_rom_find_poses.untouched

    tick, esc = SimpleNamespace(type="TIMER", value="NOTHING"), SimpleNamespace(type="ESC", value="PRESS")
    driver = Driver(RomInBackground(scene.facecap, what="Find Poses", use_markers=False))
    assert driver.modal(bpy.context, tick) == {"RUNNING_MODAL"}
    assert driver._session.status().startswith("Find Poses: measuring 24 poses of facecap-24 in ")
    assert driver.modal(bpy.context, esc) == {"CANCELLED"}
    go.set()
    driver._session.thread.join()
    assert driver.reports[-1][0] == "WARNING" and "the timeline markers are as they were" in driver.reports[-1][1]
    assert _rom_marks(scene) == {"smile": 77} and old.frame == 77
    driver = Driver(RomInBackground(scene.facecap, what="Find Poses", use_markers=False))
    driver._session.thread.join()
    assert driver.modal(bpy.context, tick) == {"FINISHED"}
    assert len(_rom_marks(scene)) == 24 and driver.reports[-1][0] == "INFO"


def test_a_skipped_pose_is_named_and_left_unmarked(draw):
    d, _ = draw
    session = rom_session(d.actor, SHEETS[SHEET], np.random.default_rng([SEED, 5]), stable=DENSE_HEAD, skip=(5,))
    scene = _scene(d)
    s = scene.facecap
    s.calib_collection = import_scene.create_take(scene, session.markers, "ROM skipped", set_scene_range=False)
    try:
        assert bpy.ops.facecap.rom_find_poses() == {"FINISHED"}
    except RuntimeError as exc:  # refused: then the error names the pose
        assert "eyes shut" in str(exc)
        return
    marks = _rom_marks(scene)  # measured on this session: named in a warning, the other 23 marked
    assert "eyes shut" not in marks and len(marks) == 23
    notes = RomInBackground(s, what="test", use_markers=False).wait().found.notes  # what Find Poses warned
    assert any("not found" in n and "eyes shut" in n for n in notes), notes


def test_a_dragged_marker_moves_the_hold_measured_and_a_stray_marker_is_named(draw):
    d, _ = draw
    scene = _scene(d)
    assert bpy.ops.facecap.rom_find_poses() == {"FINISHED"}
    s = scene.facecap
    before = RomInBackground(s, what="test", use_markers=True).wait().found
    assert before.given
    j = [p.label for p in before.poses].index("jaw open")
    session = d.roms[SHEET]
    rest = int(session.holds[0, 1] + (session.holds[1, 0] - session.holds[0, 1]) // 2)  # between jaw open and smile
    marker = next(m for m in scene.timeline_markers if m.name == rom_markers.PREFIX + "jaw open")
    marker.frame += 4  # a nudge inside the hold: the hold found moves with it
    nudged = RomInBackground(s, what="test", use_markers=True).wait().found
    assert nudged.middles[j] == marker.frame
    assert np.subtract(nudged.frames[j], before.frames[j]).tolist() == [4, 4]
    marker.frame = rest  # dragged into the rest after the pose: measured around the marker
    after = RomInBackground(s, what="test", use_markers=True).wait().found
    assert after.middles[j] == rest and after.frames[j][0] < rest < after.frames[j][1]
    size = [float(np.linalg.norm(np.nan_to_num(f.measured[j]))) for f in (before, after)]
    assert size[1] < 0.2 * size[0], size  # the face at rest there (measured: 1 % of the pose's motion)
    others = [k for k in range(len(before.poses)) if k != j]
    np.testing.assert_allclose(after.measured[others], before.measured[others])  # the other holds stay
    marker.name = rom_markers.PREFIX + "yawn"
    with pytest.raises(RuntimeError, match="'ROM: yawn'.*no pose of the ROM sheet 'facecap-24'"):
        bpy.ops.facecap.rom_save_profile(filepath=str(Path(bpy.app.tempdir) / "never.npz"))
    with pytest.raises(RuntimeError, match="'ROM: yawn'"):
        bpy.ops.facecap.solve()


def _rmse(d, result):
    metrics = compare(result.weights, result.shape_names, d.truth, d.shape_names, frames=d.performance_frames)
    return metrics["all"]["rmse"]


def test_save_performer_profile_serves_a_later_solve_of_the_actor(draw, tmp_path):
    d, csv = draw
    scene = _scene(d, source="FILE", csv=csv)  # the ROM take read from its CSV
    s = scene.facecap
    assert bpy.ops.facecap.rom_find_poses() == {"FINISHED"}
    foreign = tmp_path / "mine.npz"
    np.savez(foreign, mine=np.arange(3))  # somebody's file: not replaced without Overwrite
    with pytest.raises(RuntimeError, match="not a performer profile or library facecap wrote.*Overwrite"):
        bpy.ops.facecap.rom_save_profile(filepath=str(foreign))
    assert set(np.load(foreign)) == {"mine"} and not s.actor_profile
    path = tmp_path / "actor"
    assert bpy.ops.facecap.rom_save_profile(filepath=str(path)) == {"FINISHED"}
    assert Path(bpy.path.abspath(s.actor_profile)) == path.with_suffix(".npz")
    profile = Basis.load_npz(path.with_suffix(".npz"))
    assert profile.n_shapes >= 40 and set(profile.marker_names) == set(d.markers.names)
    assert bpy.ops.facecap.rom_save_profile(filepath=str(path)) == {"FINISHED"}  # its own file: replaced
    with_rom = _rmse(d, scene_solve.solve_take(s, scene))  # the sheet still chosen: the ROM measured in the solve
    s.calib_sheet = "NONE"  # a later take: the profile alone
    with_profile = _rmse(d, scene_solve.solve_take(s, scene))
    s.actor_profile = ""
    nothing = _rmse(d, scene_solve.solve_take(s, scene))
    # measured on this draw: 0.042 with the profile (the same with the ROM), 0.207 knowing nothing
    assert with_profile < 0.6 * nothing and with_rom == pytest.approx(with_profile, abs=0.01), \
        (with_profile, with_rom, nothing)


def test_a_rom_on_camera_marks_its_poses_and_saves_the_scores_response(tmp_path):
    """A ROM take tracked from video (*Track Face Landmarks* keeps the blendshape scores on its collection) is the
    performer's ROM on camera: Find Poses marks the poses found in the scores, Save Performer Profile writes their
    response on that camera (no measured shapes) and makes it the Performer Profile, which a later landmark take's
    scores are read through. The take here is synthetic: landmarks that move with the ROM's weights and a camera
    whose blendshape head reads each shape at 40-90 % plus a resting level."""
    from facecap.facecap_addon.scene import take as scene_take
    from facecap.solvers import MarkerSet
    from facecap.solvers.rom import ARKIT_51
    from facecap.solvers.tools.synthetic.realism.rom import rom_weights
    from facecap.solvers.video.landmarks import NAMES, RIGID
    from facecap.solvers.video.follow import PerformerMap
    from facecap.solvers.video.response import profile_contents, save_profile

    fps, rng = 30.0, np.random.default_rng(4)
    weights, performed, holds, _ = rom_weights(ARKIT_51, SHEETS[SHEET], rng, fps=fps)
    names = tuple(RIGID) + tuple(n for n in NAMES[:200] if n not in RIGID)[:40]
    base = rng.normal(0.0, 0.04, (len(names), 3))
    moving = np.zeros((len(ARKIT_51), len(names), 3))
    moving[:, len(RIGID):] = rng.normal(0.0, 0.004, (len(ARKIT_51), len(names) - len(RIGID), 3))
    positions = base + np.einsum("fk,kmd->fmd", weights, moving) + rng.normal(0.0, 2e-5, (len(weights),) + base.shape)
    markers = MarkerSet(names, np.arange(1.0, len(weights) + 1), positions, fps=fps, units="m")
    response, rest = rng.uniform(0.4, 0.9, len(ARKIT_51)), rng.uniform(0.0, 0.15, len(ARKIT_51))
    scores = np.clip(response * weights + rest + rng.normal(0.0, 0.01, weights.shape), 0.0, 1.0)

    bpy.ops.wm.open_mainfile(filepath=str(SAMPLES / "character.blend"))
    scene = bpy.context.scene
    coll = _scored_take(scene, markers, scores, ARKIT_51, "ROM clip landmarks")
    s = scene.facecap
    s.target, s.strategy, s.actor_template = bpy.data.objects["Face"], "semantic", "none"
    s.calib_collection, s.calib_sheet = coll, SHEET
    s.neutral_first, s.neutral_last = 1, int(holds[0, 0]) - 5  # the lead-in rest, for the later take below

    assert bpy.ops.facecap.rom_find_poses() == {"FINISHED"}
    marks = _rom_marks(scene)
    labels = [SHEETS[SHEET][j].label for j in performed]
    middles = 0.5 * (holds[:, 0] + holds[:, 1])
    near = [label for label, m in zip(labels, middles) if label in marks and abs(marks[label] - m) <= 5]
    assert len(near) >= 0.9 * len(labels), (sorted(set(labels) - set(near)), marks)  # no pose misnamed either
    assert all(label in near for label in marks), marks

    path = tmp_path / "performer.npz"
    assert bpy.ops.facecap.rom_save_profile(filepath=str(path)) == {"FINISHED"}
    shapes, got = profile_contents(path)
    assert not shapes and got is not None and got.sheet == SHEET
    assert bpy.path.abspath(s.actor_profile) == str(path)
    assert len(got.changed()) >= 20  # most of the sheet's shapes are read differently by this camera
    # a later landmark take of this performer: its scores are read through the profile's response
    s.marker_collection = coll
    found = scene_solve.landmark_scores(s, scene_take.markers_from_collection(s), scene_take.retarget_settings(s))
    assert found is not None and found.response is not None and found.response.sheet == SHEET
    # a profile that holds a guide followed too (written headless): the sidebar's take fuses through its map as well
    both = tmp_path / "both.npz"
    save_profile(both, response=got, performer=PerformerMap(("jawOpen", "mouthClose"), np.eye(4), np.ones((4, 2)),
                                                            0.01, 1.0, "guide.csv"))
    s.actor_profile = str(both)
    found = scene_solve.landmark_scores(s, scene_take.markers_from_collection(s), scene_take.retarget_settings(s))
    assert found.response.sheet == SHEET and found.performer.guide == "guide.csv"
    # the ROM: markers the user keeps (dragged or not) are where the poses are measured, as for a marker ROM
    keep = {"ROM: jaw open", "ROM: smile"}
    for m in [m for m in scene.timeline_markers if m.name.startswith("ROM: ") and m.name not in keep]:
        scene.timeline_markers.remove(m)
    placed = tmp_path / "placed.npz"
    assert bpy.ops.facecap.rom_save_profile(filepath=str(placed)) == {"FINISHED"}
    _, few = profile_contents(placed)
    asked = {shape for p in SHEETS[SHEET] if "ROM: " + p.label in keep for shape, _ in p.weights}
    assert few.changed() and set(few.changed()) <= asked, (few.changed(), asked)
    scene.timeline_markers["ROM: smile"].frame = len(weights) + 50
    with pytest.raises(RuntimeError, match="'ROM: smile'.*outside the ROM clip"):
        bpy.ops.facecap.rom_save_profile(filepath=str(tmp_path / "outside.npz"))


def test_a_landmark_take_that_followed_a_guide_saves_the_performers_map(tmp_path):
    """*Guide* under Actor calibration (a landmark take keeping its scores): *Save Performer Profile* solves the take
    onto the character, finds where the guide was performed (15 frames after 30 of rest) and stores the performer's
    clip in the fusion map; the Performer Profile then fuses a later landmark take through it. The take is synthetic:
    landmarks that move with the weights performed and a camera whose blendshape head reads each shape at 40-90 %."""
    from facecap.facecap_addon.scene import take as scene_take
    from facecap.solvers import MarkerSet
    from facecap.solvers.rom import ARKIT_51
    from facecap.solvers.video.landmarks import NAMES, RIGID
    from facecap.solvers.video.response import profile_contents, profile_performer

    fps, rng, late, rest = 30.0, np.random.default_rng(8), 15, 30
    t = np.arange(240)
    guide = np.clip(sum(rng.uniform(0.3, 1.0, len(ARKIT_51))
                        * np.exp(-0.5 * ((t[:, None] - rng.uniform(0, 240, len(ARKIT_51))) / 10.0) ** 2)
                        for _ in range(2)), 0.0, 1.0)
    weights = np.zeros((rest + late + 240 + 20, len(ARKIT_51)))
    weights[rest + late:rest + late + 240] = guide
    bpy.ops.wm.open_mainfile(filepath=str(SAMPLES / "character.blend"))
    face = bpy.data.objects["Face"]
    verts = np.empty(len(face.data.vertices) * 3)
    face.data.vertices.foreach_get("co", verts)
    world = np.asarray(face.matrix_world)
    verts = verts.reshape(-1, 3) @ world[:3, :3].T + world[:3, 3]
    names = tuple(RIGID) + tuple(n for n in NAMES[:200] if n not in RIGID)[:40]
    picked = rng.choice(len(verts), len(names), replace=False)
    base = verts[picked]  # on the character's skin, moving as its shapes move: a binding fits
    moving = np.zeros((len(ARKIT_51), len(names), 3))
    blocks = face.data.shape_keys.key_blocks
    for k, shape in enumerate(ARKIT_51):
        if shape in blocks:
            co = np.empty(len(verts) * 3)
            blocks[shape].data.foreach_get("co", co)
            moving[k, len(RIGID):] = ((co.reshape(-1, 3) @ world[:3, :3].T + world[:3, 3]) - verts)[
                picked[len(RIGID):]]
    positions = base + np.einsum("fk,kmd->fmd", weights, moving) + rng.normal(0.0, 2e-5, (len(weights),) + base.shape)
    markers = MarkerSet(names, np.arange(1.0, len(weights) + 1), positions, fps=fps, units="m")
    scores = np.clip(rng.uniform(0.4, 0.9, len(ARKIT_51)) * weights + rng.normal(0.0, 0.01, weights.shape), 0, 1)
    rows = ["Timecode,BlendShapeCount," + ",".join(n[0].upper() + n[1:] for n in ARKIT_51)]  # Live Link Face's
    rows += [f"00:00:{f // 30:02d}:{f % 30:02d}.000,{len(ARKIT_51)}," + ",".join(f"{v:.4f}" for v in guide[f])
             for f in range(240)]
    (tmp_path / "guide.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")

    scene = bpy.context.scene
    coll = _scored_take(scene, markers, scores, ARKIT_51, "Guide clip landmarks")
    s = scene.facecap
    s.target, s.strategy, s.actor_template = bpy.data.objects["Face"], "semantic", "none"
    s.calib_collection, s.calib_sheet, s.binding_mode = coll, "NONE", "nearest"  # as Track Face Landmarks sets it
    assert why_not(bpy.context) is not None and "Guide" in why_not(bpy.context)
    s.calib_guide = str(tmp_path / "guide.csv")
    assert why_not(bpy.context) is None

    path = tmp_path / "performer.npz"
    assert bpy.ops.facecap.rom_save_profile(filepath=str(path)) == {"FINISHED"}
    assert profile_contents(path) == (False, None)
    performer = profile_performer(path)
    assert performer.guide == "guide.csv" and performer.clips == 8.0  # FOLLOW_SHARE of the map's 24 clips
    assert bpy.path.abspath(s.actor_profile) == str(path)
    fit = RomInBackground(s, what="Save Performer Profile", use_markers=True).wait()
    assert abs(fit.offset - (rest + late)) <= 2 and fit.correlation > 0.5, fit.summary
    # a later landmark take of this performer: fused through the performer's map
    s.marker_collection = coll
    found = scene_solve.landmark_scores(s, scene_take.markers_from_collection(s), scene_take.retarget_settings(s))
    assert found.performer is not None and found.performer.guide == "guide.csv"
    # a guide on a take without blendshape scores is refused with the reason
    plain = import_scene.create_take(scene, markers, "Plain markers")
    s.calib_collection = plain
    with pytest.raises(RuntimeError, match="a guide followed calibrates a landmark take's blendshape scores"):
        bpy.ops.facecap.rom_save_profile(filepath=str(tmp_path / "other.npz"))
    assert not (tmp_path / "other.npz").exists()


def _scored_take(scene, markers, scores, names, name):
    """A landmark take's collection as *Track Face Landmarks* leaves it: the markers as empties, remembered as the
    scene's take, its blendshape ``scores`` (F, S) on ``names`` kept beside them."""
    from types import SimpleNamespace

    from facecap.facecap_addon.scene.landmark_scores import store_scores

    coll = import_scene.create_take(scene, markers, name)
    import_scene.remember_take(scene, markers, Path(name), coll)
    store_scores(coll, SimpleNamespace(blendshapes=scores, blendshape_names=names, markers=markers))
    return coll
