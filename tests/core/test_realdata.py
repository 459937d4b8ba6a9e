"""Every real capture file of the corpus, read and compared file by file (see realdata_corpus.py).

Skips when the corpus (``shared/data/realdata`` beside the checkout, ``tests/shared_data.py``) is absent or the
``test`` extra's reference readers (ezc3d, py-c3d) are not installed.
"""

from pathlib import Path

import numpy as np
import pytest

import realdata_corpus as corpus
from shared_data import skip_without

pytestmark = skip_without(corpus.CORPUS)

#: The only C3D files facecap may refuse, and the real cause its message must name.
REFUSED_C3D = {
    "btk_Empty.c3d": "empty file (0 bytes)",
    "ezc3d_Kistler.c3d": "no 3D points (POINT:USED 0): the file holds only 16 analog channels",
    "ezc3d_C3DRotationExample.c3d": "no 3D points (POINT:USED 0): the file holds 21 rotation matrices",
}
#: C3D files no reference reads correctly: facecap's reading must match their own header.
HEADER_C3D = {
    "btk_badParameterOffset.c3d", "btk_mocap36.c3d", "c3dorg_06_MACsample.c3d", "c3dorg_11_evart.c3d",
    "c3dorg_18_bad_parameter_section.c3d", "c3dorg_27_kyowadengyo.c3d", "c3dorg_29_Facial-Sing.c3d",
}
REFUSED_TRC = {"btk_Empty.trc": "empty file", "btk_Truncated.trc": "truncated TRC header: 2 of 5 header lines"}


@pytest.fixture(scope="module")
def c3d():
    pytest.importorskip("ezc3d", reason="the test extra's ezc3d is the C3D reference")
    pytest.importorskip("c3d", reason="the test extra's py-c3d is the second C3D reference")
    return {o.file: o for o in corpus.c3d_outcomes()}


@pytest.fixture(scope="module")
def trc():
    return {o.file: o for o in corpus.trc_outcomes()}


@pytest.fixture(scope="module")
def llf():
    return {o.file: o for o in corpus.llf_outcomes()}


def test_every_c3d_file_with_points_is_read_and_agrees(c3d):
    assert len(c3d) == 76
    refused = {name: o.reason for name, o in c3d.items() if o.result == "refused"}
    assert set(refused) == set(REFUSED_C3D)
    for name, cause in REFUSED_C3D.items():
        assert cause in refused[name], (name, refused[name])
    header = {name for name, o in c3d.items() if o.agreement.startswith("header")}
    assert header == HEADER_C3D
    for name, o in c3d.items():
        if name not in REFUSED_C3D and name not in HEADER_C3D:
            assert o.agreement.startswith(("ezc3d: exact", "ezc3d: float32", "py-c3d: exact", "py-c3d: float32")), (
                name, o.agreement)


def test_c3d_files_that_disagree_with_themselves_are_read_as_their_size_says(c3d):
    opto = c3d["ezc3d_Optotrak.c3d"]
    assert (opto.frames, opto.markers) == (29, 54) and opto.agreement == "ezc3d: exact"
    assert "warning: 1149 frames declared, the file holds 29 (truncated): read 29" in opto.notes
    mm = c3d["c3dorg_24_MotionMonitorC3D.c3d"]
    assert mm.agreement == "ezc3d: exact"
    assert any("the header says 16 analog samples per frame, the ANALOG parameters 112" in n for n in mm.notes)
    kyowa = c3d["c3dorg_27_kyowadengyo.c3d"]
    assert (kyowa.frames, kyowa.markers) == (152, 11)
    assert any("POINT:USED says 12 points, the header 11; the file's size fits 11" in n for n in kyowa.notes)
    for name in ("btk_parameterOverflow.c3d", "c3dorg_13_Dance.c3d", "c3dorg_13_golfswing.c3d", "c3dorg_13_Dance1.c3d"):
        assert c3d[name].result == "read" and "exact" in c3d[name].agreement, name  # parameter blocks overflow


def test_repeated_c3d_labels_are_kept_suffixed_and_named_in_a_warning():
    from facecap.solvers.io import import_markers, read_markers

    path = corpus.CORPUS / "c3d" / "btk_Gait.c3d"
    result = import_markers(path)
    names = result.markers.names
    assert len(names) == len(set(names)) == 33
    assert "RKNE" in names and "RKNE_2" in names
    warning = next(n for n in result.notes if n.startswith("warning: POINT:LABELS repeats"))
    assert "'RKNE' -> 'RKNE_2'" in warning and "'LFOO' -> 'LFOO_2'" in warning
    with pytest.warns(UserWarning, match="POINT:LABELS repeats 6 name"):
        read_markers(path)


def test_facial_sing_reads_as_a_face(c3d):
    from facecap.solvers.io import import_markers

    got = import_markers(corpus.CORPUS / "c3d" / "c3dorg_29_Facial-Sing.c3d").markers
    assert (got.n_frames, got.n_markers, got.fps, got.units) == (3000, 38, 100.0, "mm")
    extent = np.nanmax(got.positions[0], axis=0) - np.nanmin(got.positions[0], axis=0)
    assert 100 < extent.max() < 400  # a head, in millimetres


def test_every_trc_file_but_the_empty_and_truncated_ones_reads_its_rows_exactly(trc):
    assert len(trc) == 21
    refused = {name: o.reason for name, o in trc.items() if o.result == "refused"}
    assert set(refused) == set(REFUSED_TRC)
    for name, cause in REFUSED_TRC.items():
        assert cause in refused[name]
    for name, o in trc.items():
        if name not in REFUSED_TRC:
            assert o.agreement == "rows: exact", (name, o.agreement)


def test_trc_unnamed_columns_and_double_tab_headers(trc):
    gait = trc["btk_Gait.trc"]
    assert gait.markers == 105
    assert any("line 4 names 33 (NumMarkers 66): the other 72 are read as unnamed_34..unnamed_105" in n
               for n in gait.notes)
    for name in ("opensim_ExpData_motion_capture_walk.trc", "opensim_ExpData_static_walk_2.trc"):
        assert not any("not understood" in n or "guessed" in n for n in trc[name].notes), trc[name].notes


def test_live_link_face_weights_are_linear_interpolation_of_the_rows(llf):
    assert set(llf) == {"llf_alex_rom_3.csv", "llf_alex_rom_4.csv"}
    for path in sorted((corpus.CORPUS / "llf").iterdir()):
        err, track = corpus.llf_errors(path)
        assert err < 1e-9, (path.name, err)  # times of day: float rounding only
        assert track.fps == 30.0 and track.frames[0] == 1.0
        assert np.array_equal(track.frames, np.arange(1, len(track.frames) + 1))


def test_docs_table_is_current(c3d, trc, llf):
    text = (Path(__file__).resolve().parents[2] / "docs" / "realdata.md").read_text(encoding="utf-8")
    expected = corpus.table(list(c3d.values()) + list(trc.values()) + list(llf.values()))
    assert expected in text, "docs/realdata.md is stale: python tests/core/realdata_corpus.py --write docs/realdata.md"
