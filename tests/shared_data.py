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


def require(path):
    """``path`` (shared data) when it exists; otherwise the test is skipped on a developer's machine and fails in
    CI (``FACECAP_CI=1``), where the shared folder is expected beside the checkout."""
    import pytest

    if Path(path).exists():
        return Path(path)
    message = f"shared data not found: {path} (set FACECAP_SHARED to the folder holding data/)"
    if os.environ.get("FACECAP_CI"):
        pytest.fail(message)
    pytest.skip(message)
