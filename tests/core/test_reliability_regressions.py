"""Regression tests named after the defects of the second reliability campaign (``shared/bugs/reliability-2``),
the ones that need no Blender: every command's outputs through the one output policy, bad track configs,
batch summaries, hostile names in every writer, full disks, huge coordinates, inputs that are not files.
(The .blend, concurrency, resume and signal cases are in ``tests/e2e/test_reliability_cli.py``.)"""

import errno
import json
import os
import shutil
import socket
import stat
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from facecap.facecap_addon.batch.batch import run_batch
from facecap.facecap_addon.headless.headless import preflight
from facecap.solvers.config import load_take_config
from facecap.solvers.errors import ConfigError, FacecapError, InputFileError
from facecap.solvers.io import import_markers, read_weights, write_markers
from facecap.solvers.io.csv import read_weights_csv
from facecap.solvers.io.csv_write import write_weights_csv
from facecap.solvers.io.files import write_text_atomic
from facecap.solvers.io.outputs import Output, OutputError, check_free_space, check_outputs, output_mark
from facecap.solvers.markers import MarkerSet
from facecap.solvers.tools.batch_summary import read_previous
from facecap.solvers.transforms import best_rotation

cv2 = pytest.importorskip("cv2")
from facecap.solvers.video.cli import main as track  # noqa: E402

SAMPLES = Path(__file__).resolve().parents[2] / "sample_blends"
HOSTILE_NAMES = ("smile,Left", 'say "cheese"', "brauen_hoch_ä", "眉", "x" * 200, "semi;colon", "pipe|bar", "a b")


def digest(*paths):
    return {p.name: p.read_bytes() for p in paths}


@pytest.fixture
def footage(tmp_path):
    rng = np.random.default_rng(0)
    base = cv2.GaussianBlur((rng.random((48, 64)) * 255).astype(np.uint8), (5, 5), 1.5)
    (tmp_path / "seq").mkdir()
    for i in range(5):
        cv2.imwrite(str(tmp_path / "seq" / f"f{i + 1:03d}.png"), np.roll(base, i, axis=1))
    (tmp_path / "points.csv").write_text("name,x,y\na,20,20\nb,40,24\nc,30,30\n")
    return tmp_path


def track_config(folder, output, extra=""):
    path = folder / "self.toml"
    path.write_text(f'[source]\nvideo = "seq/f%03d.png"\nfps = 30\n[tracking]\npoints = "points.csv"\n{extra}'
                    f'[output]\n{output}\n')
    return path


@pytest.mark.parametrize("output", ['markers = "points.csv"', 'markers = "self.toml"', 'markers = "seq/f003.png"',
                                    'markers = "sub/../points.csv"',
                                    'markers = "o/a.csv"\nconfidence = "o/a.csv"'])
def test_01_14_track_never_writes_over_its_inputs_or_loses_an_output(footage, capsys, output):
    (footage / "sub").mkdir()
    config = track_config(footage, output)
    inputs = [config, footage / "points.csv", *sorted((footage / "seq").iterdir())]
    before = digest(*inputs)
    assert track(["track", "--config", str(config)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("facecap: error:") and ("a command never writes over" in err[0]
                                                                         or "are the same file" in err[0])
    assert digest(*inputs) == before and not (footage / "o").exists()


@pytest.mark.parametrize("tracking, message", [
    ('fps_x = 1\n', r"\[tracking.fps_x\] unknown key"),
    ('win_size = "abc"\n', r"\[tracking.win_size\] expected an integer; got 'abc'"),
    ('levels = -5\n', r"\[tracking.levels\] expected an integer >= 0 and <= 10"),
    ('win_size = 1000000000\n', r"\[tracking.win_size\] expected an integer >= 3 and <= 255"),
    ('fb_threshold = nan\n', r"\[tracking.fb_threshold\] expected a finite number"),
])
def test_14_track_options_go_through_the_checked_option_table(footage, capsys, tracking, message):
    config = track_config(footage, 'markers = "o/t.csv"', tracking)
    assert track(["track", "--config", str(config)]) == 1
    import re

    assert re.search(message, capsys.readouterr().err)


def test_14_a_misspelt_track_section_is_refused_with_a_suggestion(footage, capsys):
    config = track_config(footage, 'markers = "o/t.csv"\n[outptu]\nreport = "r.json"')
    assert track(["track", "--config", str(config)]) == 1
    assert "unknown section [outptu] (did you mean 'output'?)" in capsys.readouterr().err


def batch_args(takes, summary, resume=False):
    return SimpleNamespace(takes=[str(t) for t in takes], jobs=1, scheduler=None, summary=str(summary), resume=resume,
                           replace=False, overwrite=False, argv=[])


@pytest.fixture
def shoot(tmp_path):
    (tmp_path / "takes").mkdir()
    (tmp_path / "take.csv").write_text((SAMPLES / "sample_take.csv").read_text())
    (tmp_path / "takes" / "a.toml").write_text('[source]\nmarkers = "../take.csv"\n')
    batch = tmp_path / "batch.toml"
    batch.write_text(f'[batch]\ntakes = ["takes/"]\n[defaults.target]\nblend = "{SAMPLES / "character.blend"}"\n'
                     'object = "Face"\n[defaults.stabilise]\nmarkers = "auto"\n[defaults.neutral]\nframes = [1, 30]\n'
                     '[defaults.output]\nweights = "out/{take}.csv"\n')
    return tmp_path, batch


@pytest.mark.parametrize("summary", ["batch.toml", "takes/a.toml", "take.csv", "takes", "notes.json", "fifo.json"])
def test_02_12_the_batch_summary_never_replaces_an_input_a_folder_or_someone_elses_file(shoot, summary):
    folder, batch = shoot
    (folder / "notes.json").write_text('{"mine": true}')
    os.mkfifo(folder / "fifo.json")
    before = digest(batch, folder / "takes" / "a.toml", folder / "take.csv", folder / "notes.json")
    with pytest.raises(FacecapError) as info:
        run_batch(batch_args([batch], folder / summary))
    assert "\n" not in str(info.value)
    assert digest(batch, folder / "takes" / "a.toml", folder / "take.csv", folder / "notes.json") == before
    assert stat.S_ISFIFO(os.stat(folder / "fifo.json").st_mode) and not (folder / "out").exists()


@pytest.mark.parametrize("text", [b"", b"garbage", b"[1]", b'{"facecap_batch": 1, "takes": 5}', b'{"takes": []}'])
def test_12_resume_from_what_is_not_a_summary_is_refused(tmp_path, text):
    (tmp_path / "s.json").write_bytes(text)
    with pytest.raises(FacecapError, match="--resume needs the batch's summary"):
        read_previous(tmp_path / "s.json")
    assert (tmp_path / "s.json").read_bytes() == text


def test_12_summary_records_of_the_wrong_types_are_read_safely(tmp_path):
    (tmp_path / "s.json").write_text(json.dumps({"facecap_batch": 1, "takes": [
        {"config": 1}, 5, {"config": "/x.toml", "seconds": 5, "outputs": "x", "status": 7, "digest": [1]}]}))
    records = read_previous(tmp_path / "s.json")
    assert list(records) == ["/x.toml"]
    r = records["/x.toml"]
    assert r["seconds"] == {} and r["outputs"] == {} and r["status"] != "ok" and r["digest"] is None


def test_12_a_take_recorded_done_by_its_worker_is_done_though_the_summary_lags(tmp_path):
    (tmp_path / "s.json").write_text(json.dumps({"facecap_batch": 1, "takes": [
        {"config": "/a.toml", "status": "running"}]}))
    (tmp_path / "done").mkdir()
    (tmp_path / "done" / "x.json").write_text(json.dumps({"config": "/a.toml", "status": "ok",
                                                          "digest": {"combined": "d"}}))
    assert read_previous(tmp_path / "s.json", done=tmp_path / "done")["/a.toml"]["status"] == "ok"


def test_15a_a_linked_take_config_in_a_folder_is_one_take(shoot):
    from facecap.solvers.config.batch import collect_takes

    folder, _ = shoot
    (folder / "takes" / "link.toml").symlink_to("a.toml")
    assert [t.name for t in collect_takes([folder / "takes"])] == ["a"]


def take_config(folder, output, extra=""):
    (folder / "take.csv").write_text((SAMPLES / "sample_take.csv").read_text())
    path = folder / "take.toml"
    path.write_text(f'[target]\nblend = "{SAMPLES / "character.blend"}"\nobject = "Face"\n[source]\nmarkers = '
                    f'"take.csv"\nunits = "mm"\n[stabilise]\nmarkers = "auto"\n[neutral]\nframes = [1, 30]\n{extra}'
                    f'[output]\n{output}\n')
    return path


@pytest.mark.parametrize("output, message", [
    ('report = "notes.txt"', "exists and is not a facecap report"),
    ('weights = "other.toml"', "exists and is not a weights CSV"),
    ('weights = "fifo.csv"', "is a FIFO"),
    ('blend = "loop/out.blend"', "symbolic link loop"),
    ('blend = "o/x.blend"\nweights = "o"', "is a folder of"),
    ('blend = "o2"\nweights = "o2/x.csv"', "is a folder of"),
    ('report = "sock"', "is a socket"),
])
def test_13_output_paths_are_refused_before_any_work(tmp_path, output, message):
    (tmp_path / "notes.txt").write_text("my notes\n")
    (tmp_path / "other.toml").write_text('[source]\nmarkers = "x.csv"\n')
    os.mkfifo(tmp_path / "fifo.csv")
    (tmp_path / "loop").symlink_to("loop")
    with socket.socket(socket.AF_UNIX) as sock:
        sock.bind(str(tmp_path / "sock"))
    config = load_take_config(take_config(tmp_path, output))
    with pytest.raises(ConfigError, match=message) as info:
        preflight(config)
    assert "\n" not in str(info.value)
    assert (tmp_path / "notes.txt").read_text() == "my notes\n" and (tmp_path / "fifo.csv").is_fifo()


def test_13_overwrite_lets_an_output_replace_someone_elses_file_never_an_input(tmp_path):
    (tmp_path / "notes.txt").write_text("my notes\n")
    preflight(load_take_config(take_config(tmp_path, 'report = "notes.txt"')), overwrite=True)
    with pytest.raises(ConfigError, match="is the same file as"):
        preflight(load_take_config(take_config(tmp_path, 'report = "take.csv"')), overwrite=True)


def test_an_existing_file_is_replaced_only_when_facecap_wrote_it(tmp_path):
    """A weights CSV exported by another tool has facecap's format but not its mark: refused; facecap's
    own is replaced; a copy the user made of facecap's is the user's (the mark is not copied)."""
    out = Output("[output.weights]", tmp_path / "w.csv", "weights_csv")
    (tmp_path / "w.csv").write_text("frame,jawOpen\n1,0.5\n")
    if output_mark(tmp_path / "w.csv") is None:
        pytest.fail("this file system keeps no extended attributes: the mark cannot be tested here")
    with pytest.raises(OutputError, match="exists and is not a weights CSV .* facecap wrote"):
        check_outputs([out])
    write_weights_csv(tmp_path / "w.csv", np.arange(1, 3), ["jawOpen"], np.zeros((2, 1)))
    check_outputs([out])
    shutil.copy(tmp_path / "w.csv", tmp_path / "copy.csv")
    with pytest.raises(OutputError, match="exists and is not"):
        check_outputs([Output("[output.weights]", tmp_path / "copy.csv", "weights_csv")])


def test_a_weights_csv_whose_columns_read_like_coordinates_is_still_facecaps_own(tmp_path):
    """A rig's controls are bone channels (``lip.T.L_x``): its weights CSV reads like a marker CSV. The mark
    records what facecap wrote, so a re-run replaces its own weights and still refuses to take its
    markers CSV for weights."""
    if output_mark(tmp_path) is None:
        pytest.fail("this file system keeps no extended attributes: the mark cannot be tested here")
    controls = ["lip.T.L_x", "lip.T.L_y", "jaw_master_x"]
    write_weights_csv(tmp_path / "w.csv", np.arange(1, 3), controls, np.zeros((2, 3)))
    assert output_mark(tmp_path / "w.csv") == "weights_csv"
    check_outputs([Output("[output.weights]", tmp_path / "w.csv", "weights_csv")])
    m = MarkerSet(("a", "b"), np.arange(1, 3), np.zeros((2, 2, 3)), fps=60, units="mm")
    write_markers(tmp_path / "m.csv", m)
    with pytest.raises(OutputError, match="exists and is not a weights CSV"):
        check_outputs([Output("[output.weights]", tmp_path / "m.csv", "weights_csv")])


def test_06_every_writer_gives_hostile_names_back_or_refuses_them_by_name(tmp_path):
    rng = np.random.default_rng(1)
    m = MarkerSet(HOSTILE_NAMES, np.arange(1, 6), rng.normal(size=(5, len(HOSTILE_NAMES), 3)), fps=60, units="mm",
                  segments={"happy, then sad": [(1.0, 3.0)]})
    for ext in (".csv", ".json", ".trc", ".c3d"):
        path = tmp_path / f"t{ext}"
        try:
            write_markers(path, m)
        except FacecapError as exc:  # refused: it names the names it cannot hold
            assert ext in (".c3d",) and "x" * 200 in str(exc), (ext, exc)
            continue
        back = import_markers(path).markers
        assert back.names == m.names, ext
        np.testing.assert_allclose(back.positions, m.positions, rtol=1e-6, atol=1e-9)
    short = MarkerSet(HOSTILE_NAMES[:4], np.arange(1, 6), rng.normal(size=(5, 4, 3)), fps=60, units="mm")
    write_markers(tmp_path / "s.c3d", short)  # non-ASCII kept (UTF-8), not turned into '??'
    assert import_markers(tmp_path / "s.c3d").markers.names == short.names
    names = [*HOSTILE_NAMES, " edge "]
    write_weights_csv(tmp_path / "w.csv", np.arange(1, 4), names, rng.random((3, len(names))))
    assert read_weights_csv(tmp_path / "w.csv")[1] == tuple(names)
    assert tuple(read_weights(tmp_path / "w.csv").names) == tuple(names)
    with pytest.raises(FacecapError, match="cannot hold a line break"):
        write_weights_csv(tmp_path / "n.csv", np.arange(1, 4), ["a\nb"], rng.random((3, 1)))


def test_08_a_full_disk_is_one_line_naming_the_file(tmp_path, monkeypatch):
    def full(src, dst):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "replace", full)
    with pytest.raises(OutputError, match=r"r.json: cannot be written: no space left on the device"):
        write_text_atomic(tmp_path / "r.json", "{}")
    assert os.listdir(tmp_path) == []


def test_08_free_space_is_checked_before_the_solve(tmp_path):
    with pytest.raises(OutputError, match="not enough free space"):
        check_free_space([(Output("[output.blend]", tmp_path / "o.blend", "blend"), 1 << 62)])
    check_free_space([(Output("[output.blend]", tmp_path / "o.blend", "blend"), 1000)])


@pytest.mark.parametrize("scale", [1e300, 1e30, 1e12])
def test_09_coordinates_beyond_any_capture_are_refused_by_the_reader(tmp_path, scale):
    lines = (SAMPLES / "sample_take.csv").read_text().splitlines()[:40]
    rows = [lines[0]] + [",".join([r.split(",")[0]] + [str(float(v) * scale) if v else "" for v in r.split(",")[1:]])
                         for r in lines[1:]]
    (tmp_path / "huge.csv").write_text("\n".join(rows) + "\n")
    with pytest.raises(InputFileError, match="coordinates reach .* a damaged file, or the wrong units"):
        import_markers(tmp_path / "huge.csv", units="mm")


def test_09_the_rotation_fit_survives_extreme_scales_and_refuses_non_finite(tmp_path):
    rng = np.random.default_rng(2)
    H = rng.normal(size=(4, 3, 3))
    np.testing.assert_allclose(best_rotation(H * 1e200), best_rotation(H), atol=1e-12)
    np.testing.assert_allclose(best_rotation(H * 1e-200), best_rotation(H), atol=1e-12)
    with pytest.raises(FacecapError, match="not finite"):
        best_rotation(np.full((1, 3, 3), np.inf))


def test_15b_inputs_that_are_not_regular_files_are_refused_without_reading(tmp_path):
    os.mkfifo(tmp_path / "fifo.csv")
    for read in (import_markers, read_weights):
        with pytest.raises(InputFileError, match="is a FIFO"):
            read(tmp_path / "fifo.csv")
    with pytest.raises(InputFileError, match="is a character device"):
        import_markers("/dev/zero")


def test_policy_refuses_an_output_inside_an_image_sequence_folder_or_pattern(tmp_path):
    (tmp_path / "seq").mkdir()
    (tmp_path / "seq" / "f001.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    for out in ("seq/f001.png", "seq/f002.png", "seq/x.csv"):
        with pytest.raises(OutputError, match="never writes over what it reads"):
            check_outputs([Output("OUT", tmp_path / out, "markers_csv")], {"[source.video]": tmp_path / "seq"})
    with pytest.raises(OutputError, match="image sequence"):
        check_outputs([Output("OUT", tmp_path / "f007.png", "png")], {"[source.video]": tmp_path / "f%03d.png"})
