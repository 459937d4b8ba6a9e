"""A test that needs the shared data and cannot find it says, in its skip reason, what the data is, where it is
published and where the tests look (issue 40: 56 tests skipped for anyone without the folder, some naming only
an internal path)."""

import shared_data
from shared_data import BLENDERFACE, ICT_FACEKIT, REALDATA, SHARED, reason


def test_each_shared_folder_a_test_needs_says_where_to_get_it():
    for path in (REALDATA / "c3d" / "c3dorg_29_Facial-Sing.c3d", REALDATA / "llf" / "llf_alex_rom_3.csv",
                 REALDATA / "edge-cases", BLENDERFACE, ICT_FACEKIT / "ict_face.npz"):
        text = reason(path)
        assert text.startswith("needs data/") and f"not found at {path}" in text, text
        assert "github.com/" in text and "FACECAP_SHARED" in text and str(SHARED) in text, text
    assert "c3dorg_29_Facial-Sing.c3d" in reason(REALDATA / "c3d" / "c3dorg_29_Facial-Sing.c3d")
    assert "opensim-org/opensim-core" in reason(REALDATA / "edge-cases")
    assert "template fetch" in reason(ICT_FACEKIT)


def test_every_shared_folder_has_a_source():
    used = {"realdata", "realdata/edge-cases", "blenderface", "ict-facekit", "bugs"}
    assert used <= set(shared_data.SOURCES)
