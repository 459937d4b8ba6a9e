"""Shared by every test folder: facecap's data folder is the user's (an installed human template changes what
`[actor] template = "auto"` solves with), so the suite starts from an empty one; tests that install a template
point FACECAP_DATA elsewhere themselves. Likewise a landmark take uses the Face Landmarker bundle when one is
installed: the suite always names the shared copy (never a download), so what it runs does not depend on the
machine's cache; tests of the older models ask for them (``bundle=None``). And a command run in-process (``-v``)
leaves facecap's logger as it found it for the next test, whatever the order the folders run in."""

import logging
import os
import warnings

import pytest
from shared_data import FACE_LANDMARKER


@pytest.fixture(autouse=True, scope="session")
def empty_facecap_data(tmp_path_factory):
    previous = os.environ.get("FACECAP_DATA")
    os.environ["FACECAP_DATA"] = str(tmp_path_factory.mktemp("facecap-data"))
    yield
    if previous is None:
        os.environ.pop("FACECAP_DATA", None)
    else:
        os.environ["FACECAP_DATA"] = previous


@pytest.fixture(autouse=True, scope="session")
def shared_face_landmarker():
    previous = os.environ.get("FACECAP_FACE_LANDMARKER")
    if FACE_LANDMARKER.is_file():
        os.environ["FACECAP_FACE_LANDMARKER"] = str(FACE_LANDMARKER)
    else:
        os.environ.pop("FACECAP_FACE_LANDMARKER", None)
    yield
    if previous is None:
        os.environ.pop("FACECAP_FACE_LANDMARKER", None)
    else:
        os.environ["FACECAP_FACE_LANDMARKER"] = previous


@pytest.fixture(autouse=True)
def facecap_logger_restored():
    """The package logger's level, handlers and propagation and ``warnings.showwarning`` put back after each test:
    a command run in-process with ``--verbose`` would otherwise print every later test's Blender lines."""
    log = logging.getLogger("facecap")
    kept = (log.level, list(log.handlers), log.propagate, warnings.showwarning)
    yield
    log.setLevel(kept[0])
    log.handlers[:] = kept[1]
    log.propagate = kept[2]
    warnings.showwarning = kept[3]
