"""`facecap convert` and `facecap inspect --json`: every format to every format, weights files
recognised, one line and exit 1 on bad input, the input never overwritten, hints instead of guesses."""

import hashlib
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from facecap.solvers import MarkerSet
from facecap.solvers.io import import_markers, read_markers, read_weights, write_markers
from facecap.solvers.tools.convert import main as convert
from facecap.solvers.tools.inspect import main as inspect

ROOT = __import__("pathlib").Path(__file__).resolve().parents[2]


def take(units="mm", seed=3):
    rng = np.random.default_rng(seed)
    pos = rng.normal(size=(30, 4, 3)) * 40 + [0, 0, 1500]
    pos[5:9, 2] = np.nan
    return MarkerSet(("brow_L", "brow_R", "lip", "chin"), np.arange(1, 31), pos, fps=100, units=units,
                     segments={"posed_happy": [(4.0, 12.0)]})


def digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def one_line(capsys):
    out = capsys.readouterr()
    return out.out.strip().splitlines(), out.err.strip().splitlines()


@pytest.mark.parametrize("src_ext", [".c3d", ".trc", ".csv", ".json"])
@pytest.mark.parametrize("out_ext", [".c3d", ".trc", ".csv", ".json"])
def test_convert_every_marker_format_to_every_other(tmp_path, capsys, src_ext, out_ext):
    m = take()
    src = tmp_path / f"in{src_ext}"
    write_markers(src, m)
    before = digest(src)
    out = tmp_path / f"out{out_ext}"
    assert convert([str(src), str(out)] + (["--units", "mm"] if src_ext == ".csv" else [])) == 0
    lines, err = one_line(capsys)
    assert len(lines) == 1 and lines[0].startswith(f"facecap convert: wrote {out}") and err == []
    got = read_markers(out, units="mm" if out_ext == ".csv" else None)
    assert got.names == m.names and got.units == "mm"
    np.testing.assert_array_equal(got.frames, m.frames)
    np.testing.assert_allclose(got.positions, m.positions, rtol=1e-6, atol=1e-6)  # float32 in C3D
    assert digest(src) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([src.name, out.name])  # no temporary left


def test_convert_out_units_and_reading_options(tmp_path, capsys):
    m = take(units="m")
    src = tmp_path / "in.csv"
    write_markers(src, m)
    assert convert([str(src), str(tmp_path / "out.c3d"), "--units", "cm", "--out-units", "mm", "--fps", "50"]) == 0
    got = read_markers(tmp_path / "out.c3d")
    assert got.units == "mm" and got.fps == 50
    np.testing.assert_allclose(got.positions, m.positions * 10, rtol=1e-6)  # cm numbers, written in mm
    assert "units given, fps given" in capsys.readouterr().out


def test_convert_refuses_the_input_as_output_in_every_spelling(tmp_path, capsys):
    src = tmp_path / "take.c3d"
    write_markers(src, take())
    before = digest(src)
    (tmp_path / "sub").mkdir()
    os.symlink(src, tmp_path / "link.c3d")
    os.link(src, tmp_path / "hard.c3d")
    for out in (src, tmp_path / "sub" / ".." / "take.c3d", tmp_path / "link.c3d", tmp_path / "hard.c3d"):
        assert convert([str(src), str(out)]) == 1
        lines, err = one_line(capsys)
        assert lines == [] and len(err) == 1 and "OUT is the same file as IN" in err[0], out
    assert digest(src) == before


@pytest.mark.parametrize("args, message", [
    (["missing.c3d", "out.csv"], "file not found"),
    (["take.c3d", "out.xlsx"], "cannot write '.xlsx'; use .csv, .c3d, .trc, .json"),
    (["take.c3d", "notes.csv"], "exists and is not a marker CSV"),  # someone's file: --overwrite to replace
    (["take.c3d", "afile/out.csv"], "afile is a file, not a folder"),
    (["take.c3d", "adir"], "cannot write 'no extension'"),
    (["bad.csv", "out.json"], "line 2, field 'a_y': expected a number, got 'zero'"),
    (["take.c3d", "out.csv", "--out-units", "px"], None),
])
def test_convert_bad_input_is_one_line_and_exit_1(tmp_path, capsys, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    write_markers(tmp_path / "take.c3d", take())
    (tmp_path / "bad.csv").write_text("frame,a_x,a_y,a_z\n1,0,zero,0\n")
    (tmp_path / "adir").mkdir()
    (tmp_path / "notes.csv").write_text("frame notes: not a take\n")
    (tmp_path / "afile").write_text("x")
    listing = sorted(os.listdir(tmp_path))
    if message is None:  # argparse: usage error, exit 2
        with pytest.raises(SystemExit) as exc:
            convert(args)
        assert exc.value.code == 2
        return
    assert convert(args) == 1
    lines, err = one_line(capsys)
    assert lines == [] and len(err) == 1 and message in err[0], err
    assert sorted(os.listdir(tmp_path)) == listing


def llf_file(path, rows=40, rate=60, drop=()):
    head = "Timecode,BlendShapeCount,EyeBlinkLeft,JawOpen,HeadYaw,HeadPitch,HeadRoll"
    lines = []
    for i in range(rows):
        if i in drop:
            continue
        ff = 2 * i + 0.25  # every other timecode frame: 30 fps samples at a 60 fps timecode
        s, ff = divmod(ff, rate)
        lines.append(f"13:13:{4 + int(s):02d}:{ff:06.3f},61,{i / rows:.6f},{0.5 + 0.01 * i:.6f},0.1,0.2,0.3")
    path.write_text(head + "\n" + "\n".join(lines) + "\n")


def test_convert_live_link_face_to_the_weights_csv_at_fps(tmp_path, capsys):
    src = tmp_path / "take.csv"
    llf_file(src)
    assert convert([str(src), str(tmp_path / "w.csv"), "--fps", "60"]) == 0
    line = capsys.readouterr().out.strip()
    assert "79 frames x 2 shapes at 60 fps from livelinkface; head angles left out" in line
    track = read_weights(tmp_path / "w.csv")
    assert track.names == ("eyeBlinkLeft", "jawOpen") and track.values.shape == (79, 2)
    np.testing.assert_allclose(track.values[::2, 1], 0.5 + 0.01 * np.arange(40), atol=1e-9)
    np.testing.assert_allclose(track.values[1::2, 1], 0.505 + 0.01 * np.arange(39), atol=1e-9)  # halfway


def test_inspect_json_for_markers_says_how_units_and_rate_were_decided(tmp_path, capsys):
    m = take()
    src = tmp_path / "take.csv"
    write_markers(src, m)
    assert inspect([str(src), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["kind"] == "markers" and data["format"] == "csv" and data["names"] == list(m.names)
    assert data["frames"] == {"count": 30, "first": 1.0, "last": 30.0}
    assert (data["units"], data["units_from"]) == ("mm", "guessed")
    assert (data["fps"], data["fps_from"]) == (60.0, "assumed")  # a CSV has no rate: noted, not silent
    assert data["gaps"]["lip"] == {"samples": 4, "runs": 1, "longest": 4}
    assert data["segments"] == {"posed_happy": [[4.0, 12.0]]}
    assert any(n.startswith("units not given: guessed mm") and "--units" in n for n in data["notes"])
    assert any(n.startswith("frame rate assumed: 60 fps") for n in data["notes"])
    assert inspect([str(src), "--json", "--units", "mm", "--fps", "100"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert (data["units_from"], data["fps_from"]) == ("given", "given")


def test_inspect_recognises_a_live_link_face_file_as_weights(tmp_path, capsys):
    src = tmp_path / "take.csv"
    llf_file(src)
    assert inspect([str(src), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["kind"] == "weights" and data["format"] == "livelinkface"
    assert data["names"] == ["eyeBlinkLeft", "jawOpen"] and data["head"] is True
    assert data["fps"] == 30.0 and data["fps_from"] == "timecode" and data["timecode"] == "13:13:04:00.250"
    assert data["frames"]["count"] == 40 and data["units"] is None
    assert inspect([str(src)]) == 0
    assert "(livelinkface, solved weights)" in capsys.readouterr().out


def test_inspect_bad_file_is_one_line_and_exit_1(tmp_path, capsys):
    (tmp_path / "bad.trc").write_text("PathFileType\t4\n")
    assert inspect([str(tmp_path / "bad.trc"), "--json"]) == 1
    lines, err = one_line(capsys)
    assert lines == [] and len(err) == 1 and "truncated TRC header" in err[0]


def test_cli_runs_convert_and_inspect(tmp_path):
    src = tmp_path / "take.c3d"
    write_markers(src, take())
    run = [sys.executable, "-m", "facecap"]
    done = subprocess.run(run + ["convert", str(src), str(tmp_path / "t.trc")], capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 0 and done.stdout.count("\n") == 1 and "wrote" in done.stdout
    done = subprocess.run(run + ["inspect", str(tmp_path / "t.trc"), "--json"], capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 0 and json.loads(done.stdout)["frames"]["count"] == 30
    done = subprocess.run(run + ["convert", str(src), str(src)], capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 1 and done.stdout == "" and done.stderr.count("\n") == 1


def test_y_up_files_get_a_hint_and_up_axis_converts(tmp_path):
    m = take(units="mm")
    y_up = m.positions[..., [0, 2, 1]] * [1, 1, -1]  # heights on Y (1.5 m), depth on -Z
    src = tmp_path / "yup.trc"
    write_markers(src, MarkerSet(m.names, m.frames, y_up, fps=100, units="mm"))
    result = import_markers(src)
    hint = [n for n in result.notes if n.startswith("hint:")]
    assert len(hint) == 1 and "median y 1.50 m" in hint[0] and 'set up_axis = "Y"' in hint[0]
    result = import_markers(src, up_axis="Y")
    assert not any(n.startswith("hint:") for n in result.notes)
    np.testing.assert_allclose(result.markers.positions, m.positions, atol=1e-9)
    z_up = import_markers(tmp_path / "yup.trc", up_axis="Z")
    assert not any(n.startswith("hint:") for n in z_up.notes)
    write_markers(tmp_path / "zup.trc", m)
    assert not any(n.startswith("hint:") for n in import_markers(tmp_path / "zup.trc").notes)


def test_blender_unit_files_are_questioned_and_scaled(tmp_path):
    m = take(units="m")
    bu = MarkerSet(m.names, m.frames, (m.positions - [0, 0, 1500]) / 1000 * 5, fps=100, units="m")  # 0.2 m-ish x 5
    write_markers(tmp_path / "bu.csv", bu)
    note = next(n for n in import_markers(tmp_path / "bu.csv").notes if n.startswith("units not given"))
    assert "is not a face's size: for Blender units set units = \"bu\" and unit_scale" in note
    got = read_markers(tmp_path / "bu.csv", units="bu", unit_scale=0.2)
    assert got.units == "m"
    np.testing.assert_allclose(got.positions, (m.positions - [0, 0, 1500]) / 1000, atol=1e-9)
