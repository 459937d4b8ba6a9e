"""Where the tests find the data nobody on the team wrote: the ``shared/`` folder beside the checkout
(``../shared`` from the repository root), or the folder named by ``FACECAP_SHARED``. Never an absolute path
of a development machine: any clone with ``shared/`` beside it runs the real-data tests."""

import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def shared_root():
    """The shared folder (``FACECAP_SHARED``, else ``<checkout>/../shared``); it may not exist."""
    env = os.environ.get("FACECAP_SHARED")
    return Path(env).expanduser().resolve() if env else ROOT.parent / "shared"


SHARED = shared_root()
#: Real C3D / TRC / Live Link Face captures (``SOURCES.md`` there); ``FACECAP_REALDATA`` still overrides.
REALDATA = Path(os.environ["FACECAP_REALDATA"]) if os.environ.get("FACECAP_REALDATA") else SHARED / "data" / "realdata"
BLENDERFACE = SHARED / "data" / "blenderface"
ICT_FACEKIT = SHARED / "data" / "ict-facekit"
#: MediaPipe's Face Landmarker bundle (the copy every test uses: tests never download it)
FACE_LANDMARKER = SHARED / "data" / "mediapipe" / "face_landmarker.task"
FACECAP_HEAD = SHARED / "data" / "facecap-head" / "facecap_head.npz"
BUGS = SHARED / "bugs"


#: Where each folder of the shared data comes from, for someone without it: all of it is third-party data under
#: its own licence, kept out of the repository; each is public except the project's own bug reproducers.
SOURCES = {
    "realdata": "real captures from public repositories: c3d.org's sample files (github.com/biomechanics-foundation/"
                "c3dio, tests/c3d_org_samples; sample 29 is Facial-Sing.c3d, saved as c3d/c3dorg_29_Facial-Sing.c3d), "
                "github.com/pyomeca/ezc3d-testFiles, Biomechanical-ToolKit/BTKData, opensim-org/opensim-models (TRC) "
                "and alexdjulin/LiveLinkFace-CSV-Retarget-For-Motionbuilder (anim/alex_rom_*.csv, saved as "
                "llf/llf_alex_rom_*.csv); docs/realdata.md lists every file",
    "realdata/edge-cases": "four files from other writers: github.com/opensim-org/opensim-core (OpenSim/Sandbox/"
                           "MatlabScripts/test_walking.trc), github.com/pyomeca/pyomeca (tests/data/markers.trc), "
                           "github.com/JMTechArt/Pipeline-Examples (a Live Link Face CSV) and "
                           "github.com/sentien-io/SentienLiveLinkFace (recording/recording.csv)",
    "blenderface": "the two captures of the blenderFace R package (github.com/axzinker/blenderFace: Subject_01.csv, "
                   "Subject_02.csv, Blender_Scalingdata.csv)",
    "ict-facekit": "the ICT Face Model's face region (github.com/ICT-VGL/ICT-FaceKit, MIT) reduced to ict_face.npz "
                   "(keys in tests/ict_release_copy.py); `python -m facecap template fetch` installs the same model "
                   "for the add-on but not this copy",
    "bugs": "the project's own reproducers of reported bugs (not published; these tests run on the project's machines)",
}


def reason(path):
    """Why a test that needs ``path`` of the shared data cannot run here, and how to get it: what the data is and
    where it is published, and where the tests look (``FACECAP_SHARED``, else ``shared/`` beside the checkout)."""
    rel = Path(path).resolve().relative_to(SHARED) if Path(path).resolve().is_relative_to(SHARED) else Path(path)
    parts = rel.parts[1:] if rel.parts[:1] == ("data",) else rel.parts
    source = next((SOURCES[k] for k in ("/".join(parts[:2]), "/".join(parts[:1])) if k in SOURCES),
                  "the project's shared data")
    return (f"needs {rel.as_posix()} of the shared data, not found at {path}: {source}. Put such a folder at "
            f"{SHARED} (shared/data/... beside the checkout) or set FACECAP_SHARED to it")


def skip_without(path):
    """A ``pytest.mark.skipif`` for tests that need ``path`` of the shared data, with ``reason(path)``."""
    import pytest

    return pytest.mark.skipif(not Path(path).exists(), reason=reason(path))


def require(path):
    """``path`` (shared data) when it exists; otherwise the test is skipped on a developer's machine and fails in
    CI (``FACECAP_CI=1``), where the shared folder is expected beside the checkout."""
    import pytest

    if Path(path).exists():
        return Path(path)
    if os.environ.get("FACECAP_CI"):
        pytest.fail(reason(path))
    pytest.skip(reason(path))
