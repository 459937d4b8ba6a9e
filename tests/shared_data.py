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
BUGS = SHARED / "bugs"
