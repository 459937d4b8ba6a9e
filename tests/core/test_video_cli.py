"""`track --config take.toml`: footage -> wide marker CSV (pixels), progress on stderr, one-line errors."""

import json
import re
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("cv2")

from facecap.solvers import read_markers_csv, read_weights_csv  # noqa: E402
from facecap.facecap_addon.cli import main  # noqa: E402  (facecap track, as a user runs it)
from facecap.solvers.video.synthetic import write_synthetic_clip  # noqa: E402


@pytest.fixture(scope="module")
def take(tmp_path_factory):
    d = tmp_path_factory.mktemp("take")
    clip = write_synthetic_clip(d / "clip.avi", 24, 200, 150, seed=6)
    (d / "points2d.csv").write_text("name,x,y\nbrow_L,80,50\nbrow_R,120,50\nmouth,100,110\n")
    return d, clip


def write_config(d, tracking, extra=""):
    cfg = d / "take.toml"
    cfg.write_text(f'[source]\nvideo = "clip.avi"\n\n[tracking]\n{tracking}\n\n'
                   f'[output]\nmarkers = "out/tracks.csv"\nconfidence = "out/conf.csv"\nreport = "out/track.json"\n{extra}')
    return cfg


@pytest.mark.parametrize("method", ["lk", "dis"])
def test_track_writes_wide_csv_in_pixels(take, method, capsys):
    d, clip = take
    cfg = write_config(d, f'points = "points2d.csv"\nmethod = "{method}"\nreference = 1')
    assert main(["track", "--config", str(cfg)]) == 0
    out, err = capsys.readouterr()
    assert f"track ({method}): 24/24 frames" in err and "tracked 3 points over 24 frames" in out
    header = (d / "out/tracks.csv").read_text().splitlines()[0]
    assert header == "frame,brow_L_x,brow_L_y,brow_R_x,brow_R_y,mouth_x,mouth_y"
    mk = read_markers_csv(d / "out/tracks.csv", units="px", fps=30.0)
    assert mk.frames[0] == 1 and mk.frames[-1] == 24  # frame 1 = the first frame, as in Blender
    np.testing.assert_allclose(mk.positions[0], [[80, 50], [120, 50], [100, 110]], atol=1e-6)
    truth = np.stack([clip.motion.forward(t, mk.positions[0]) for t in range(24)])
    assert np.median(np.linalg.norm(mk.positions - truth, axis=2)) <= 0.5
    frames, names, conf = read_weights_csv(d / "out/conf.csv")
    assert names == mk.names and conf.shape == (24, 3) and (conf <= 1).all()
    report = json.loads((d / "out/track.json").read_text())
    assert report["footage"]["fps"] == 30.0 and report["footage"]["width"] == 200 and report["method"] == method
    assert report["reference"] == 1 and report["footage"]["frames"] == [1, 24]


@pytest.mark.parametrize("section,key,message", [
    ("tracking", "reference = 0", r"\[tracking.reference\] frame 0 does not exist: frames count from 1"),
    ("source", "first = 0", r"\[source.first\] frame 0 does not exist: frames count from 1"),
    ("source", "frame_offset = 1", r"\[source.frame_offset\] `frame_offset` was removed: frames count from 1"),
])
def test_old_zero_based_frame_numbers_are_told_not_shifted(take, capsys, section, key, message):
    d, _ = take
    if section == "tracking":
        cfg = write_config(d, f'points = "points2d.csv"\n{key}')
    else:
        cfg = d / "take.toml"
        cfg.write_text(f'[source]\nvideo = "clip.avi"\n{key}\n[tracking]\npoints = "points2d.csv"\n'
                       '[output]\nmarkers = "out/tracks.csv"\n')
    assert main(["track", "--config", str(cfg)]) == 1
    err = capsys.readouterr().err.strip()
    assert re.search(message, err) and "add 1 to" in err and len(err.splitlines()) == 1


def test_track_region_from_a_subprocess(take):
    d, _ = take
    cfg = write_config(d, "region = [50, 30, 100, 100]\nmax_points = 20")
    run = subprocess.run([sys.executable, "-m", "facecap.solvers.video.cli", "track", "--config", str(cfg)],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    mk = read_markers_csv(d / "out/tracks.csv", units="px", fps=30.0)
    assert 5 <= mk.n_markers <= 20 and mk.n_frames == 24


@pytest.mark.parametrize("tracking,extra,message", [
    ('points = "points2d.csv"\nmethod = "sift"', "",
     r"\[tracking.method\] expected one of lk, dis, farneback, tvl1, landmarks; got 'sift'"),
    ('points = "points2d.csv"\nregion = [0, 0, 10, 10]', "", "exactly one of"),
    ('region = [0, 0, 10]', "", r"\[tracking.region\] expected a list of 4 numbers"),
    ('points = "missing.csv"', "", "missing.csv: file not found"),
    ('points = "points2d.csv"\ncolour = 1', "", r"\[tracking.colour\] unknown key; known keys: points, region"),
    ('points = "points2d.csv"\nmethod = "dis"\nwin_size = 11', "", "do not apply to method 'dis'"),
])
def test_config_errors_are_one_line_and_exit_non_zero(take, capsys, tracking, extra, message):
    d, _ = take
    cfg = write_config(d, tracking, extra)
    assert main(["track", "--config", str(cfg)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("facecap: error: ")
    assert pytest.importorskip("re").search(message, err[0]), err[0]


def test_unreadable_video_and_missing_config(tmp_path, capsys):
    (tmp_path / "clip.avi").write_bytes(b"\x00" * 100)
    (tmp_path / "p.csv").write_text("a,1,1\n")
    cfg = write_config(tmp_path, 'points = "p.csv"')
    assert main(["track", "--config", str(cfg)]) == 1
    assert "cannot decode as video" in capsys.readouterr().err
    assert main(["track", "--config", str(tmp_path / "nope.toml")]) == 1
    assert "config file not found" in capsys.readouterr().err


def test_progress_false_cancels_before_anything_is_written(take, capsys):
    from facecap.solvers.video.cli import load_track_config, run_track
    from facecap.solvers.video.reading import Cancelled

    d, _ = take
    cfg = write_config(d, 'points = "points2d.csv"').read_text().replace("out/", "stopped/")
    (d / "stopped.toml").write_text(cfg)
    settings = load_track_config(d / "stopped.toml")
    with pytest.raises(Cancelled, match=r"cancelled at frame 5 \(5 of 24 frames done\)"):
        run_track(settings, progress=lambda done, total: done < 5)
    assert not (d / "stopped").exists()


def test_ctrl_c_stops_cleanly_with_one_line_and_no_output(take):
    """SIGINT during `python -m facecap track`: 'cancelled at frame N', exit 130, no markers file."""
    import os
    import signal
    import time

    d, _ = take
    # TV-L1 takes ~0.5 s a frame here, so the signal lands mid-take.
    cfg = write_config(d, 'points = "points2d.csv"\nmethod = "tvl1"').read_text().replace("out/", "interrupted/")
    (d / "interrupted.toml").write_text(cfg)
    proc = subprocess.Popen([sys.executable, "-m", "facecap", "track", "--config", str(d / "interrupted.toml")],
                            stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, cwd=d)
    seen, deadline = b"", time.monotonic() + 60
    while b"track (tvl1): " not in seen and time.monotonic() < deadline:
        chunk = os.read(proc.stderr.fileno(), 4096)
        if not chunk:
            break
        seen += chunk
    assert b"track (tvl1): 1/24 frames" in seen, seen
    proc.send_signal(signal.SIGINT)
    rest = proc.communicate(timeout=60)[1]
    lines = (seen + rest).decode().splitlines()
    assert proc.returncode == 130
    assert len([line for line in lines if "cancelled" in line]) == 1
    assert pytest.importorskip("re").fullmatch(r"facecap: cancelled at frame \d+ \(\d+ of 24 frames done\); "
                                               r"nothing written", lines[-1]), lines
    assert "Traceback" not in "\n".join(lines)
    assert not (d / "interrupted").exists()
