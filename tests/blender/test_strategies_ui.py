"""The strategies from the sidebar: Solve panel options by strategy, calibration poses, mapping table,
examples from an action, solved weights; every new operator through bpy.ops; settings saved in the .blend."""

import sys
from pathlib import Path
from types import SimpleNamespace

import bpy
import numpy as np
import pytest

from scene_fixtures import LayoutStub, build_character, draw_panel

from facecap.facecap_addon.scene import anim, import_scene, layers
from facecap.solvers.character.basis import Basis
from facecap.solvers.tools.compare import SAMPLE_BASIS, STABLE, _phone_weights, actor_take, calibration_weights, make_actor
from facecap.solvers.io.csv import write_markers_csv
from facecap.solvers.tools.synthetic.synth import performance_weights, synthesize_take

sys.path.insert(0, str(Path(__file__).resolve().parent))

STRATEGIES = ("semantic", "geometric", "calibrated", "parallel", "linear", "rbf", "pca", "refine")


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """An actor with its own proportions and expressions (calibration + performance) and the sample character."""
    out = tmp_path_factory.mktemp("ui")
    character = Basis.load_npz(SAMPLE_BASIS)
    actor = make_actor(character, seed=0)
    Wc, poses, neutral = calibration_weights(actor.shape_names, hold=30)
    calib = synthesize_take(actor, Wc, rest=30, stable=STABLE, units="mm", actor_scale=1.0, gap_fraction=0.0,
                            max_deg=10.0, seed=5)
    write_markers_csv(out / "calib.csv", calib.markers)
    truth = performance_weights(character.shape_names, 600, seed=0)
    take = actor_take(actor, truth, gaps=0.05, seed=2)
    write_markers_csv(out / "take01.csv", take.markers)
    phone, names = _phone_weights(truth, character.shape_names)
    rows = ["Timecode,BlendShapeCount," + ",".join(names)]
    rows += [f"00:00:{f // 60:02d}:{f % 60:02d}.000,{len(names)}," + ",".join(f"{v:.6f}" for v in values)
             for f, values in enumerate(phone)]
    (out / "llf.csv").write_text("\n".join(rows) + "\n")
    return SimpleNamespace(dir=out, character=character, calib=calib.markers, poses=poses, neutral=neutral,
                           truth=truth, take=take)


@pytest.fixture
def scene(empty_scene, data):
    obj = build_character(data.character)
    assert bpy.ops.facecap.import_markers(filepath=str(data.dir / "take01.csv"), units="mm", fps=60.0) == {"FINISHED"}
    s = empty_scene.facecap
    s.target = obj
    s.neutral_first, s.neutral_last = 1, 60
    assert sorted(m.name for m in s.markers if m.stable) == sorted(STABLE)
    return SimpleNamespace(scene=empty_scene, s=s, obj=obj)


def _solved(obj, names):
    key = obj.data.shape_keys
    _, values = anim.read_curves(key, [(f'key_blocks["{n}"].value', 0) for n in names], action=layers.solved_action(key))
    return values


def _add_poses(scene, poses):
    scene.use_preview_range = True
    for name, (first, last) in poses.items():
        scene.facecap.calib_pose_name = name
        scene.frame_preview_start, scene.frame_preview_end = first, last
        assert bpy.ops.facecap.calib_pose_add() == {"FINISHED"}
    scene.use_preview_range = False


def test_calibrated_solve_from_the_sidebar(scene, data):
    s = scene.s
    s.strategy = "calibrated"
    with pytest.raises(RuntimeError, match=r"strategy 'calibrated' needs \[calibration\] markers and poses"):
        bpy.ops.facecap.solve()
    # calibration take as a collection of empties (an imported calibration session)
    s.calib_collection = import_scene.create_take(scene.scene, data.calib, "calib", set_scene_range=False)
    scene.scene.use_preview_range = True
    scene.scene.frame_preview_start, scene.scene.frame_preview_end = data.neutral
    assert bpy.ops.facecap.calib_neutral_from_timeline() == {"FINISHED"}
    assert (s.calib_neutral_first, s.calib_neutral_last) == tuple(data.neutral)
    _add_poses(scene.scene, data.poses)
    assert len(s.calib_poses) == len(data.poses) and s.calib_poses[0].name == "eyeBlinkLeft"
    assert bpy.ops.facecap.solve() == {"FINISHED"}
    solved = _solved(scene.obj, data.character.shape_names)
    rmse = float(np.sqrt(np.mean(np.nan_to_num(solved - data.truth, nan=1.0) ** 2)))
    print(f"calibrated from the sidebar: RMSE {rmse:.4f}")
    assert rmse <= 0.04
    assert "(calibrated)" in s.last_report


def test_semantic_from_the_sidebar_says_what_it_knew_of_the_actor(scene, data):
    """The default strategy: with nothing known it solves and says so in the panel; with the calibration
    session's poses it solves the actor's own shapes (tier "calibration")."""
    s = scene.s
    assert s.strategy == "semantic" and s.actor_tier == ""
    assert bpy.ops.facecap.solve() == {"FINISHED"}
    assert s.actor_tier.startswith("character: ") and "(semantic)" in s.last_report
    nothing = _solved(scene.obj, data.character.shape_names)
    s.calib_collection = import_scene.create_take(scene.scene, data.calib, "calib", set_scene_range=False)
    s.calib_neutral_first, s.calib_neutral_last = data.neutral
    _add_poses(scene.scene, data.poses)
    assert bpy.ops.facecap.solve() == {"FINISHED"}
    assert s.actor_tier.startswith("calibration: solved against the actor's own calibration poses")
    solved = _solved(scene.obj, data.character.shape_names)
    rmse = float(np.sqrt(np.mean(np.nan_to_num(solved - data.truth, nan=1.0) ** 2)))
    before = float(np.sqrt(np.mean(np.nan_to_num(nothing - data.truth, nan=1.0) ** 2)))
    print(f"semantic from the sidebar: RMSE {before:.4f} nothing known, {rmse:.4f} calibrated")
    assert rmse <= 0.04 and rmse < before
    labels = [text for kind, text in draw_panel("FACECAP_PT_solve").calls if kind == "label"]
    assert any(t and t.startswith("calibration: solved against") for t in labels)


def test_calibration_from_file_with_mapping_table(scene, data):
    s = scene.s
    s.strategy = "calibrated"
    s.calib_source, s.calib_path, s.calib_units = "FILE", str(data.dir / "calib.csv"), "mm"
    s.calib_neutral_first, s.calib_neutral_last = data.neutral
    _add_poses(scene.scene, data.poses)
    assert bpy.ops.facecap.mapping_fill_by_name() == {"FINISHED"}
    assert len(s.mapping) == 52 and all(r.source == r.target and r.gain == 1.0 for r in s.mapping)
    s.mapping[0].gain = 0.0  # eyeBlinkLeft is driven by nothing now
    assert bpy.ops.facecap.solve() == {"FINISHED"}
    solved = _solved(scene.obj, data.character.shape_names)
    assert np.allclose(solved[:, 0], 0.0)
    assert solved[:, data.character.shape_names.index("jawOpen")].max() > 0.5


def test_mapping_rows_add_remove_clear(scene):
    s = scene.s
    assert not bpy.ops.facecap.mapping_remove.poll() and not bpy.ops.facecap.mapping_clear.poll()
    assert bpy.ops.facecap.mapping_add() == {"FINISHED"}
    s.mapping[0].source, s.mapping[0].target, s.mapping[0].gain = "AU26", "jawOpen", 0.8
    assert bpy.ops.facecap.mapping_add() == {"FINISHED"}
    assert bpy.ops.facecap.mapping_remove() == {"FINISHED"}
    assert len(s.mapping) == 1
    s.strategy = "geometric"
    assert not bpy.ops.facecap.mapping_fill_by_name.poll()  # geometric has no mapping
    s.strategy = "calibrated"
    with pytest.raises(RuntimeError, match="define calibration poses first"):
        bpy.ops.facecap.mapping_fill_by_name()
    assert bpy.ops.facecap.mapping_clear() == {"FINISHED"}
    assert len(s.mapping) == 0


def test_pose_from_current_frame_and_remove(scene):
    s = scene.s
    assert not bpy.ops.facecap.calib_pose_remove.poll()
    scene.scene.use_preview_range = False
    scene.scene.frame_current = 42
    s.calib_pose_name = "AU12"
    assert bpy.ops.facecap.calib_pose_add() == {"FINISHED"}
    assert (s.calib_poses[0].name, s.calib_poses[0].first, s.calib_poses[0].last) == ("AU12", 42, 42)
    s.calib_pose_name = "  "
    with pytest.raises(RuntimeError, match="type a pose name first"):
        bpy.ops.facecap.calib_pose_add()
    assert bpy.ops.facecap.calib_pose_remove() == {"FINISHED"}
    assert len(s.calib_poses) == 0


def test_parallel_from_a_weights_file_needs_no_markers(scene, data):
    s = scene.s
    s.marker_collection = None
    s.strategy = "parallel"
    assert bpy.ops.facecap.solve.poll()
    with pytest.raises(RuntimeError, match=r"strategy 'parallel' needs \[source\] weights"):
        bpy.ops.facecap.solve()
    s.weights_path = str(data.dir / "llf.csv")
    s.parallel_use_neutral, s.parallel_neutral_first, s.parallel_neutral_last = True, 1, 50
    assert bpy.ops.facecap.mapping_fill_by_name() == {"FINISHED"}
    assert len(s.mapping) == 52 and s.mapping[0].source == "eyeBlinkLeft"  # LLF names read as ARKit
    assert bpy.ops.facecap.solve() == {"FINISHED"}
    solved = _solved(scene.obj, data.character.shape_names)
    assert np.sqrt(np.mean((solved - data.truth) ** 2)) <= 0.04


@pytest.mark.parametrize("strategy", ["linear", "rbf", "pca"])
def test_examples_from_the_keyed_frames_of_an_action(scene, data, strategy):
    s = scene.s
    s.strategy = strategy
    frames = data.take.markers.frames
    picks = np.linspace(70, 590, 50).astype(int)
    values = np.full((frames.size, data.character.n_shapes), np.nan)
    values[picks] = data.truth[picks]
    key = scene.obj.data.shape_keys
    curves = [(f'key_blocks["{n}"].value', 0) for n in data.character.shape_names]
    posed = anim.new_action_with_curves(key, name="posed", curves=curves, frames=frames, values=values)
    s.examples_action = posed
    assert bpy.ops.facecap.solve() == {"FINISHED"}
    assert layers.solved_action(key) != posed and posed.name in bpy.data.actions
    assert key.animation_data.action == posed, "the user's own active action is never replaced"
    solved = _solved(scene.obj, data.character.shape_names)
    assert np.sqrt(np.mean((solved - data.truth) ** 2)) <= 0.2




def _draw(strategy, **extra):
    s = bpy.context.scene.facecap
    s.strategy = strategy
    for k, v in extra.items():
        setattr(s, k, v)
    layout = draw_panel("FACECAP_PT_solve")  # with the sub-panels that apply to the strategy
    return {name for _, name in layout.calls}


def test_solve_panel_draws_only_what_applies(scene):
    drawn = {st: _draw(st) for st in STRATEGIES}
    assert {"calib_poses", "mapping", "facecap.calib_pose_add", "facecap.mapping_fill_by_name",
            "facecap.mapping_clear", "calib_collection", "regularisation"} <= drawn["calibrated"]
    assert "calib_poses" not in drawn["geometric"] and "mapping" not in drawn["geometric"]
    assert "regions" in drawn["geometric"] and "regions" not in drawn["calibrated"]
    assert {"weights_path", "parallel_gain", "parallel_mirror", "mapping"} <= drawn["parallel"]
    assert "regularisation" not in drawn["parallel"] and "calib_poses" not in drawn["parallel"]
    assert {"examples_action", "ridge"} <= drawn["linear"] and "rbf_kernel" not in drawn["linear"]
    assert {"examples_action", "rbf_kernel", "rbf_far"} <= drawn["rbf"]
    assert {"examples_action", "pca_mode", "pca_ica"} <= drawn["pca"]
    assert {"refine_max_iterations", "calib_poses", "mapping"} <= drawn["refine"]
    assert {"actor_profile", "actor_template", "facecap.install_template", "facecap.download_template", "unseen_shapes",
            "exclusive", "calib_poses", "regularisation"} <= drawn["semantic"] and "mapping" not in drawn["semantic"]
    assert "calib_path" in _draw("calibrated", calib_source="FILE")
    assert "parallel_gamma" in _draw("parallel", parallel_curve="gamma")
    assert "smoothing_second" in _draw("pca", pca_mode="posed") and "smoothing_second" not in _draw("pca", pca_mode="related")
    items = tuple(item.identifier for item in bpy.context.scene.facecap.bl_rna.properties["strategy"].enum_items)
    assert items == STRATEGIES


@pytest.mark.parametrize("ui_list, collection, op", [("FACECAP_UL_calib_poses", "calib_poses", "calib_pose_add"),
                                                     ("FACECAP_UL_mapping", "mapping", "mapping_add")])
def test_new_lists_draw_their_items(scene, ui_list, collection, op):
    getattr(bpy.ops.facecap, op)()
    s = scene.s
    item = getattr(s, collection)[0]
    layout = LayoutStub()
    getattr(bpy.types, ui_list).draw_item(None, bpy.context, layout, s, item, 0, s, "", 0)
    assert len(layout.calls) >= 3


def test_strategy_settings_are_saved_in_the_blend(scene, tmp_path):
    s = scene.s
    s.strategy = "refine"
    _add_poses(scene.scene, {"jawOpen": (120, 135), "AU12": (200, 215)})
    bpy.ops.facecap.mapping_add()
    s.mapping[0].source, s.mapping[0].target, s.mapping[0].gain = "AU12", "mouthSmileLeft", 0.7
    s.calib_poses[1].split = True
    s.refine_stiffness = 0.05
    path = tmp_path / "saved.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=str(path))
    s = bpy.context.scene.facecap
    assert s.strategy == "refine" and s.refine_stiffness == pytest.approx(0.05)
    assert [(p.name, p.first, p.last, p.split) for p in s.calib_poses] == [("jawOpen", 120, 135, False), ("AU12", 200, 215, True)]
    assert [(r.source, r.target, round(r.gain, 6)) for r in s.mapping] == [("AU12", "mouthSmileLeft", 0.7)]
    from facecap.facecap_addon.scene.take import retarget_settings

    settings = retarget_settings(s)
    assert settings.calibration.pose_table() == {"jawOpen": [[120, 135]], "AU12": [[200, 215]]}
    assert settings.calibration.split == ("AU12",) and settings.mapping.table_dict() == {"AU12": {"mouthSmileLeft": pytest.approx(0.7)}}


def test_install_template_from_the_download(scene, tmp_path, monkeypatch):
    """Install Human Template: the ICT-FaceKit folder as downloaded (a file chosen inside it stands for it) is
    converted into facecap's data folder, hash-checked; a second install keeps it; a wrong choice is one error."""
    from ict_release_copy import write_ict_release
    from shared_data import ICT_FACEKIT, require

    from facecap.solvers.character.template import TEMPLATE_DIGEST, HumanTemplate, template_path

    monkeypatch.setenv("FACECAP_DATA", str(tmp_path / "data"))
    release = write_ict_release(require(ICT_FACEKIT) / "ict_face.npz", tmp_path / "ICT-FaceKit")
    with pytest.raises(RuntimeError, match="choose the ICT-FaceKit download"):  # bpy.ops raises an ERROR report
        bpy.ops.facecap.install_template(filepath=str(tmp_path / "nothing.zip"))
    assert not template_path().exists()
    assert bpy.ops.facecap.install_template(filepath=str(release / "FaceXModel" / "jawOpen.obj")) == {"FINISHED"}
    assert HumanTemplate.load(template_path()).model.digest == TEMPLATE_DIGEST
    stamp = template_path().stat().st_mtime_ns
    assert bpy.ops.facecap.install_template(directory=str(release)) == {"FINISHED"}
    assert template_path().stat().st_mtime_ns == stamp  # already installed: not written again
    other = tmp_path / "other"
    (other / "FaceXModel").mkdir(parents=True)
    (other / "FaceXModel" / "generic_neutral_mesh.obj").write_text("v 0 0 0\n")
    template_path().unlink()
    with pytest.raises(RuntimeError, match=r"missing from the ICT-FaceKit download \(154 of the 155"):
        bpy.ops.facecap.install_template(directory=str(other))  # the whole download is looked at before reading
    assert not template_path().exists()


def test_download_template_beside_the_interface(scene, tmp_path, monkeypatch):
    """Download Human Template (here from a local server): from a script it installs at once; with Blender's
    online access off it refuses, naming the preference and the manual route; from the sidebar it downloads on a
    worker thread (the status bar says how far) and Esc leaves nothing installed and no partial file."""
    import time
    import zipfile
    from types import SimpleNamespace

    from ict_release_copy import serve_release, write_ict_release
    from shared_data import ICT_FACEKIT, require

    from facecap.operators import actor, downloads
    from facecap.solvers.character.template import TEMPLATE_DIGEST, HumanTemplate, template_path

    monkeypatch.setenv("FACECAP_DATA", str(tmp_path / "data"))
    monkeypatch.setenv("FACECAP_CACHE", str(tmp_path / "cache"))
    folder = write_ict_release(require(ICT_FACEKIT) / "ict_face.npz", tmp_path / "ICT-FaceKit")
    archive = tmp_path / "ict.zip"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as z:
        for path in sorted(folder.rglob("*")):
            z.write(path, path.relative_to(tmp_path).as_posix())
    with serve_release(archive) as url:
        monkeypatch.setattr(downloads, "online_access", lambda: False)
        with pytest.raises(RuntimeError, match="online access is off"):
            bpy.ops.facecap.download_template(url=f"{url}/ict.zip")
        monkeypatch.setattr(downloads, "online_access", lambda: True)

        class Driver:  # the operator's modal methods on a plain object, as Blender would call them
            modal, cancel, _stop = (actor.FACECAP_OT_download_template.modal, actor.FACECAP_OT_download_template.cancel,
                                    actor.FACECAP_OT_download_template._stop)

            def __init__(self, job):
                self._job, self._timer, self.reports = job, None, []

            def report(self, kind, message):
                self.reports.append((kind.pop(), message))

        tick, esc = SimpleNamespace(type="TIMER", value="NOTHING"), SimpleNamespace(type="ESC", value="PRESS")
        driver = Driver(actor.DownloadJob(f"{url}/slow.zip"))
        while driver._job.done == 0:
            time.sleep(0.05)
        assert driver.modal(bpy.context, tick) == {"RUNNING_MODAL"}
        assert driver._job.status().startswith("Download Human Template (ICT-FaceKit da5f95a): downloading ")
        assert driver.modal(bpy.context, esc) == {"CANCELLED"}
        driver._job.thread.join(30)
        assert driver.reports == [("WARNING", "Download Human Template cancelled; nothing was installed")]
        assert not template_path().exists() and not any((tmp_path / "cache").rglob("*.part-*"))

        assert bpy.ops.facecap.download_template(url=f"{url}/ict.zip") == {"FINISHED"}
    assert HumanTemplate.load(template_path()).model.digest == TEMPLATE_DIGEST
    assert list((tmp_path / "cache" / "downloads").iterdir()) == []  # the zip removed once converted
    assert bpy.ops.facecap.download_template(url="http://127.0.0.1:9/never.zip") == {"FINISHED"}  # installed: no call
