"""Every marker format: round trips, detection, units/axes/timing, weights files, and clear errors."""

import struct
import warnings
from pathlib import Path

import numpy as np
import pytest
from shared_data import BLENDERFACE, skip_without

from facecap.solvers import InputFileError, MarkerSet
from facecap.solvers.io.c3d import read_c3d
from facecap.solvers.io.c3d_write import write_c3d
from facecap.solvers.io import detect_format, import_markers, read_markers, read_weights, write_markers



def take(frames=40, markers=5, seed=0, units="mm"):
    rng = np.random.default_rng(seed)
    pos = rng.normal(size=(frames, markers, 3)) * 20
    pos[3, 1] = np.nan
    pos[10:14, 2] = np.nan
    return MarkerSet(tuple(f"m{i}" for i in range(markers)), np.arange(5, 5 + frames), pos, fps=100,
                     units=units, segments={"posed_happy": [(8.0, 12.0)], "neutral": [(20.0, 30.0)]})


@pytest.mark.parametrize("ext, tol, keeps_fps, keeps_segments", [
    ("csv", 1e-7, False, True), ("c3d", 1e-5, True, True), ("trc", 1e-7, True, False), ("json", 0, True, True),
])
def test_round_trip_every_writer(tmp_path, ext, tol, keeps_fps, keeps_segments):
    m = take()
    write_markers(tmp_path / f"t.{ext}", m)
    result = import_markers(tmp_path / f"t.{ext}", fps=None if keeps_fps else 100, units=None if ext != "csv" else "mm")
    back = result.markers
    assert back.names == m.names and back.units == "mm" and back.fps == 100
    np.testing.assert_array_equal(back.frames, m.frames)
    np.testing.assert_array_equal(back.visible, m.visible)
    np.testing.assert_allclose(back.positions, m.positions, atol=tol * 100, equal_nan=True)
    assert back.segments == (m.segments if keeps_segments else {})


def test_detects_formats_from_extension_and_content(tmp_path):
    m = take()
    write_c3d(tmp_path / "a.c3d", m)
    (tmp_path / "noext").write_bytes((tmp_path / "a.c3d").read_bytes())
    (tmp_path / "long.csv").write_text("frame,marker,x,y,z\n1,a,1,2,3\n")
    assert detect_format(tmp_path / "noext") == "c3d"
    assert detect_format(tmp_path / "long.csv") == "csv-long"


def test_long_csv_any_column_order_and_missing_samples(tmp_path):
    path = tmp_path / "long.csv"
    path.write_text("marker;frame;z;y;x\na;1;3;2;1\nb;1;6;5;4\na;2;3;2;1,5\nb;3;1;1;1\n")
    m = read_markers(path, units="mm", fps=30)
    assert m.names == ("a", "b") and m.fps == 30
    np.testing.assert_allclose(m.positions[:, :, 0], [[1, 4], [1.5, np.nan], [np.nan, 1]])


def test_long_csv_duplicate_sample_names_line(tmp_path):
    path = tmp_path / "long.csv"
    path.write_text("frame,marker,x,y,z\n1,a,1,2,3\n1,a,1,2,3\n")
    with pytest.raises(InputFileError, match=r"long\.csv, line 3: marker 'a' appears twice"):
        read_markers(path)


def test_wide_csv_decimal_comma_tab_and_time_column(tmp_path):
    path = tmp_path / "t.tsv"
    path.write_text("time\ta_x\ta_y\ta_z\tnote\n0,0\t1,5\t2\t3\tx\n0,01\t1,6\tNA\t3\tx\n0,02\t1,7\t2\t3\t\n")
    result = import_markers(path, units="cm")
    m = result.markers
    assert m.fps == pytest.approx(100) and m.units == "cm"
    np.testing.assert_array_equal(m.frames, [0, 1, 2])
    np.testing.assert_allclose(m.positions[:, 0, 0], [1.5, np.nan, 1.7])
    assert m.segments == {"x": [(0.0, 1.0)]}


def test_variable_rate_is_resampled_and_reported(tmp_path):
    path = tmp_path / "t.csv"
    times = [0.0, 0.01, 0.025, 0.03, 0.04]
    path.write_text("timestamp,a_x,a_y\n" + "".join(f"{t},{t * 100},0\n" for t in times))
    with pytest.warns(UserWarning, match="resampled linearly to 100 fps: 5 samples -> 5 frames"):
        m = read_markers(path, fps=100, units="px")
    np.testing.assert_allclose(m.frames, [0, 1, 2, 3, 4])
    np.testing.assert_allclose(m.positions[:, 0, 0], [0, 1, 2, 3, 4])


def test_units_blender_scale_and_y_up(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("frame,a_x,a_y,a_z\n1,1,2,3\n")
    m = read_markers(path, units="bu", unit_scale=0.002, up_axis="Y")
    assert m.units == "m"
    np.testing.assert_allclose(m.positions[0, 0], [0.002, -0.006, 0.004])
    with pytest.raises(Exception, match="unit_scale"):
        read_markers(path, units="bu")


def test_c3d_int16_data_with_scale_and_analog_is_read(tmp_path):
    """A hand-built Intel C3D with int16 points (scale 0.5), 2 analog words per frame, residual -1 gaps."""
    path = tmp_path / "int.c3d"

    def param(gid, name, etype, dims, data):
        body = struct.pack("<bB", etype, len(dims)) + bytes(dims) + data + b"\x00"
        return struct.pack("<bb", len(name), gid) + name.encode() + struct.pack("<h", len(body) + 2) + body

    def group(gid, name):
        return struct.pack("<bb", len(name), -gid) + name.encode() + struct.pack("<h", 3) + b"\x00"

    params = b"".join([
        group(1, "POINT"), param(1, "USED", 2, (), struct.pack("<h", 2)),
        param(1, "SCALE", 4, (), struct.pack("<f", 0.5)), param(1, "RATE", 4, (), struct.pack("<f", 50.0)),
        param(1, "DATA_START", 2, (), struct.pack("<h", 3)), param(1, "FRAMES", 2, (), struct.pack("<h", 3)),
        param(1, "LABELS", -1, (4, 2), b"L1  R1  "), param(1, "UNITS", -1, (2,), b"mm"),
    ])
    header = bytearray(512)
    struct.pack_into("<BBhhhhhfhhf", header, 0, 2, 0x50, 2, 2, 7, 9, 0, 0.5, 3, 1, 50.0)
    section = (struct.pack("<BBBB", 1, 0x50, 1, 84) + params).ljust(512, b"\x00")
    frames = np.array([[[2, 4, 6, 0], [10, 10, 10, 0], [1, 1, 0, 0]],
                       [[2, 4, 8, 0], [0, 0, 0, -1], [1, 1, 0, 0]],
                       [[2, 4, 10, 0], [12, 10, 10, 0], [1, 1, 0, 0]]], dtype="<i2")
    path.write_bytes(bytes(header) + section + frames.reshape(3, -1)[:, :10].tobytes())
    m = read_c3d(path)
    assert m.names == ("L1", "R1") and m.units == "mm" and m.fps == 50
    np.testing.assert_array_equal(m.frames, [7, 8, 9])
    np.testing.assert_allclose(m.positions[:, 0], [[1, 2, 3], [1, 2, 4], [1, 2, 5]])
    assert m.visible[:, 1].tolist() == [True, False, True]


@pytest.mark.parametrize("name, text, match", [
    ("bad.trc", "PathFileType\t4\t(X/Y/Z)\tx\nDataRate\n60\nFrame#\tTime\ta\n\n1\t0\t1\tq\t3\n",
     r"bad\.trc, line 6, field 'aY': expected a number, got 'q'"),
    ("zero.trc", "PathFileType\t4\t(X/Y/Z)\tx\nDataRate\n60\nFrame#\tTime\ta\n\n", r"zero\.trc, line 5: zero frames"),
    ("bad.json", '{"facecap_markers": 1, "fps": 60, "markers": ["a"], "positions": [[[1, 2, "x"]]]}',
     r"bad\.json, field 'positions\[0\]\[0\]': expected null or a list of 3 finite numbers"),
    ("trunc.json", '{"facecap_markers": 1, "fps": 60,\n "markers": ["a"', r"trunc\.json, line 2: invalid JSON"),
    ("dup.json", '{"facecap_markers": 1, "fps": 60, "markers": ["a", "a"], "positions": [[null, null]]}',
     r"field 'markers': duplicate marker names"),
    ("wrong_delim.csv", "frame a_x a_y a_z\n1 0 0 0\n", r"wrong_delim\.csv, line 1: no frame column"),
    ("garbage.c3d", "hello world" * 60, r"garbage\.c3d: not a C3D file"),
    ("short.c3d", "\x02\x50", r"short\.c3d: truncated C3D header"),
])
def test_bad_files_name_file_line_or_field(tmp_path, name, text, match):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(InputFileError, match=match):
        read_markers(path)


def test_trc_repeated_names_are_kept_suffixed_with_a_warning(tmp_path):
    path = tmp_path / "dup.trc"
    path.write_text("PathFileType\t4\t(X/Y/Z)\tx\nDataRate\tNumMarkers\n60\t2\nFrame#\tTime\ta\t\t\ta\n\n"
                    "1\t0\t1\t2\t3\t4\t5\t6\n")
    with pytest.warns(UserWarning, match=r"line 4 repeats 1 name\(s\); the repeats are kept as 'a' -> 'a_2'"):
        got = read_markers(path, units="mm")
    assert got.names == ("a", "a_2")
    np.testing.assert_array_equal(got.positions[0], [[1, 2, 3], [4, 5, 6]])


def test_truncated_c3d_gives_the_frames_it_holds_with_a_warning(tmp_path):
    m = take()
    write_c3d(tmp_path / "t.c3d", m)
    data = (tmp_path / "t.c3d").read_bytes()
    (tmp_path / "t.c3d").write_bytes(data[:-100])
    with pytest.warns(UserWarning, match=r"40 frames declared, the file holds 38 \(truncated\): read 38"):
        got = read_markers(tmp_path / "t.c3d")
    assert got.n_frames == 38  # 100 bytes cut: 1.25 frames of 80 bytes
    np.testing.assert_allclose(got.positions, m.positions[:38], rtol=1e-6, atol=1e-9)
    header_and_params = 512 * (data[512 + 2] + 1)
    (tmp_path / "t.c3d").write_bytes(data[:header_and_params + 10])
    with pytest.raises(InputFileError, match=r"field 'POINT:FRAMES': truncated point data: 40 frames declared, "
                                             r"the file holds none"):
        read_markers(tmp_path / "t.c3d")


def test_unknown_option_is_refused(tmp_path):
    write_c3d(tmp_path / "t.c3d", take())
    with pytest.raises(Exception, match=r"option\(s\) \['delimiter'\] do not apply to c3d"):
        read_markers(tmp_path / "t.c3d", delimiter=";")


LLF_HEADER = ("Timecode,BlendShapeCount,EyeBlinkLeft,JawOpen,MouthSmileLeft,HeadYaw,HeadPitch,HeadRoll,"
              "LeftEyeYaw,LeftEyePitch,LeftEyeRoll,RightEyeYaw,RightEyePitch,RightEyeRoll")


def test_live_link_face_csv(tmp_path):
    rows = [f"10:00:01:{f % 30:02d}.{0 if f < 30 else 0}" for f in range(45)]
    rows = [f"10:00:{1 + f // 60:02d}:{(f % 60) // 2:02d}.{500 * (f % 2):03d}" for f in range(90)]
    lines = [LLF_HEADER] + [f"{tc},52,{f / 100:.3f},0.5,0.2,0.1,0.2,0.3,0,0,0,0,0,0" for f, tc in enumerate(rows)]
    path = tmp_path / "llf.csv"
    path.write_text("\n".join(lines) + "\n")
    t = read_weights(path)
    assert t.format == "livelinkface" and t.names == ("eyeBlinkLeft", "jawOpen", "mouthSmileLeft")
    assert t.fps == pytest.approx(60) and t.timecode == "10:00:01:00.000"
    np.testing.assert_array_equal(t.frames, np.arange(1, 91))
    np.testing.assert_allclose(t.values[:3, 0], [0, 0.01, 0.02])
    np.testing.assert_allclose(t.head[0], [0.1, 0.2, 0.3])
    assert t.eyes.shape == (90, 6)


def test_mediapipe_csv(tmp_path):
    from facecap.solvers.io.arkit import ARKIT_52

    names = ["_neutral"] + [n for n in ARKIT_52 if n != "tongueOut"]
    path = tmp_path / "mp.csv"
    path.write_text("timestamp_ms," + ",".join(names) + "\n"
                    + "".join(f"{33.333 * i:.3f}," + ",".join(["0.1"] * 52) + "\n" for i in range(10)))
    t = read_weights(path)
    assert t.format == "mediapipe" and len(t.names) == 52 and t.head is None
    assert t.fps == pytest.approx(30, rel=1e-3)


def test_weights_bad_timecode(tmp_path):
    path = tmp_path / "llf.csv"
    path.write_text(LLF_HEADER + "\nnoon,52" + ",0" * 12 + "\n")
    with pytest.raises(InputFileError, match=r"line 2, field 'Timecode': expected a timecode"):
        read_weights(path)


@skip_without(BLENDERFACE)
@pytest.mark.parametrize("subject, frames, neutral", [(1, 1714, (800, 985)), (2, 1692, (700, 940))])
def test_real_blenderface_captures(subject, frames, neutral):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = import_markers(BLENDERFACE / f"Subject_0{subject}.csv", units="bu", unit_scale=0.002 / 0.04328)
    m = result.markers
    assert m.n_markers == 16 and m.n_frames == frames and m.units == "m"
    assert set(m.segments) == {"posed_neutral", "posed_disgust", "posed_happy", "posed_fear"}
    assert m.segments["posed_neutral"] == [tuple(float(v) for v in neutral)]
    assert {"A7", "A8", "CL7", "BR2"} <= set(m.names)
