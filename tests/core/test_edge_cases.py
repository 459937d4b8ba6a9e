"""The readers on files from other writers, each showing an edge case (``shared/data/realdata/edge-cases/``,
described in ``SOURCES.md`` there), read as those notes say they should be; and a marker CSV without a
header row, described by ``[source] columns``.

Each file is compared with a plain parse of its own rows (``realdata_corpus``): the csv module for TRC,
linear interpolation of the raw rows at the frame times for Live Link Face.
"""

import csv

import numpy as np
import pytest

import realdata_corpus as corpus
from shared_data import skip_without
from facecap.solvers import FacecapError, load_take_config
from facecap.solvers.io import import_markers, read_weights
from facecap.solvers.io.weights import parse_timecode

EDGE = corpus.CORPUS / "edge-cases"
pytestmark = skip_without(EDGE)


def test_a_comma_separated_trc_reads_as_its_rows():
    """pyomeca's markers.trc: the TRC layout with commas instead of tabs (refused before, with a
    misleading 'expected Frame#' on line 4)."""
    path = EDGE / "pyomeca_markers.trc"
    got = import_markers(path)
    m = got.markers
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    names = [c for c in rows[3][2:] if c]
    assert m.names == tuple(names) and m.n_markers == 51
    assert m.units == "mm" and m.fps == 100.0 and m.n_frames == 93
    np.testing.assert_array_equal(m.positions, corpus.trc_rows(path))
    assert "comma-separated TRC" in got.notes


def test_opensim_zeros_are_gaps_not_positions():
    """OpenSim's test_walking.trc writes missing markers as 0,0,0: 10,455 of its 32,240 samples (the same
    trial's C3D has them as gaps). They must reach the solver as gaps, not as markers at the origin."""
    path = EDGE / "osim_test_walking.trc"
    got = import_markers(path)
    m = got.markers
    assert m.n_frames == 806 and m.n_markers == 40
    missing = ~m.visible
    assert int(missing.sum()) == 10_455
    with open(path, newline="", encoding="utf-8") as fh:
        rows = [r for r in csv.reader(fh, delimiter="\t")][5:]
    raw = np.array([[float(x) for x in r[2:2 + 120]] for r in rows if any(c.strip() for c in r)]).reshape(806, 40, 3)
    zero = (raw == 0).all(axis=2)
    np.testing.assert_array_equal(missing, zero)
    np.testing.assert_array_equal(m.positions[~zero], raw[~zero])
    assert not (m.positions[m.visible] == 0).all(axis=1).any()
    assert any("10455 sample(s) written as 0, 0, 0 read as gaps" in n for n in got.notes)


def _raw_live_link_face(path):
    """(seconds from the first row, names, values) parsed plainly; timecode frames at 60 per second."""
    with open(path, newline="", encoding="utf-8") as fh:
        rows = [r for r in csv.reader(fh) if r]
    t = np.array([parse_timecode(r[0], 60.0) for r in rows[1:]])
    return t - t[0], rows[0][2:], np.array([[float(x) for x in r[2:]] for r in rows[1:]])


@pytest.mark.parametrize("name, drift", [("llf_jmtechart_MySlate_3.csv", 0.13), ("llf_sentien_recording.csv", 0.5)])
def test_live_link_face_rows_off_the_frame_grid_are_resampled(name, drift):
    """Rows that drift off the frame grid (JMTechArt: up to 0.13 frame, a 59.94 fps phone stamping 60 fps
    timecodes) or step unevenly (Sentien) are interpolated onto it: every frame's weight and head and
    eye angle equals linear interpolation of the raw rows at the frame's time. Rounding each row to
    its nearest frame, as was done for the drifting file, is up to 0.018 off."""
    path = EDGE / name
    track = read_weights(path)
    t, names, values = _raw_live_link_face(path)
    lower = [n.lower() for n in names]
    tq = (track.frames - track.frames[0]) / track.fps
    assert track.fps == pytest.approx(59.94)

    def reference(channels):
        return np.stack([np.interp(tq, t, values[:, lower.index(c.lower())]) for c in channels], axis=1)

    np.testing.assert_allclose(track.values, reference(track.names), rtol=0, atol=1e-9)
    np.testing.assert_allclose(track.head, reference(("HeadYaw", "HeadPitch", "HeadRoll")), rtol=0, atol=1e-9)
    np.testing.assert_allclose(track.eyes, reference(("LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll", "RightEyeYaw",
                                                      "RightEyePitch", "RightEyeRoll")), rtol=0, atol=1e-9)
    angles = track.angles()  # named columns, radians, on the track's frames
    assert list(angles) == list(track.HEAD_CHANNELS + track.EYE_CHANNELS)
    np.testing.assert_array_equal(angles["RightEyePitch"], track.eyes[:, 4])
    note = next(n for n in track.notes if "resampled" in n)
    assert f"rows up to {drift:.2g} frame off the frame grid" in note, note
    if name.startswith("llf_jmtechart"):  # the case that was read unresampled: rows rounded to frames
        rounded = values[: len(tq)][:, [lower.index(c.lower()) for c in track.names]]
        assert np.max(np.abs(rounded - reference(track.names))) > 0.015


def test_a_marker_csv_without_a_header_row_is_described_in_the_config(tmp_path):
    """A CSV of numbers only (pyomeca's markers as an exporter without a header writes them): refused with
    the config line to write; read once ``[source] columns`` names its columns."""
    trc = import_markers(EDGE / "pyomeca_markers.trc").markers
    rows = np.column_stack([trc.frames, trc.positions.reshape(trc.n_frames, -1)])
    take = tmp_path / "noheader.csv"
    take.write_text("\n".join(",".join(f"{v:.9g}" for v in row) for row in rows) + "\n")
    with pytest.raises(FacecapError, match=r"line 1: no header row: .*\[source\] columns = "):
        import_markers(take, units="mm", fps=100)
    config = tmp_path / "take.toml"
    columns = ", ".join(f'"{n}"' for n in ("frame",) + trc.names)
    config.write_text(f'[target]\nobject = "Face"\n[source]\nmarkers = "noheader.csv"\nunits = "mm"\nfps = 100\n'
                      f'columns = [{columns}]\n[stabilise]\nmarkers = ["ASISl", "ASISr", "PSISl"]\n'
                      '[neutral]\nframes = [1, 10]\n[output]\nweights = "w.csv"\n')
    cfg = load_take_config(config)
    got = import_markers(cfg.markers_path, units=cfg.units, fps=cfg.fps, **cfg.read_options)
    assert got.markers.names == trc.names
    np.testing.assert_allclose(got.markers.positions, trc.positions, rtol=1e-8)
    with pytest.raises(FacecapError, match=r"`columns` describe 4 columns .* the first row has 154 fields"):
        import_markers(take, units="mm", columns=["frame", "ASISl"])
