"""Shared by every test folder: facecap's data folder is the user's (an installed human template changes what
`[actor] template = "auto"` solves with), so the suite starts from an empty one; tests that install a template
point FACECAP_DATA elsewhere themselves."""

import os

import pytest


@pytest.fixture(autouse=True, scope="session")
def empty_facecap_data(tmp_path_factory):
    previous = os.environ.get("FACECAP_DATA")
    os.environ["FACECAP_DATA"] = str(tmp_path_factory.mktemp("facecap-data"))
    yield
    if previous is None:
        os.environ.pop("FACECAP_DATA", None)
    else:
        os.environ["FACECAP_DATA"] = previous
