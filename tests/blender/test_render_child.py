"""``render_child.in_child``: the tests' renders run in a forked child, so one abort of software OpenGL costs a
retry (said as a warning), not the whole test run."""

import faulthandler
import os

import pytest
from render_child import ChildRenderDied, in_child


def _abort():
    """Die as Blender does when software OpenGL fails (without the fault handler's dump: it is expected)."""
    faulthandler.disable()
    os.abort()


def test_the_childs_value_comes_back():
    assert in_child(lambda: {"frames": 58, "pid": os.getpid()})["pid"] != os.getpid()


def test_an_error_in_the_child_fails_with_its_traceback():
    def fails():
        raise ValueError("no face in frame 12")

    with pytest.raises(AssertionError, match="(?s)the clip failed in its child.*ValueError: no face in frame 12"):
        in_child(fails, label="the clip")


def _fails_once(marker, fail):
    """Work that calls ``fail`` the first time it runs in any process (``marker`` records it), then renders."""

    def work():
        if not marker.exists():
            marker.touch()
            fail()
        return "rendered"

    return work


def _abort_saying_why():
    os.write(2, b"EGL Error (0x3009): EGL_BAD_MATCH\n")  # what Blender prints from C before it aborts
    _abort()


def test_a_child_that_died_once_is_tried_again_and_said(tmp_path):
    dies_once = _fails_once(tmp_path / "died", _abort_saying_why)
    with pytest.warns(ChildRenderDied, match="(?s)the clip: its child died \\(signal SIGABRT; it printed last:\n"
                                             "EGL Error \\(0x3009\\): EGL_BAD_MATCH\\); tried again"):
        assert in_child(dies_once, label="the clip") == "rendered"


def test_a_child_that_keeps_dying_fails_the_test():
    with pytest.warns(ChildRenderDied):
        with pytest.raises(AssertionError, match="its child died 2 times \\(signal SIGABRT; signal SIGABRT\\)"):
            in_child(_abort, label="the clip")


def test_a_child_that_hangs_is_killed_and_tried_again(tmp_path):
    import time

    hangs_once = _fails_once(tmp_path / "hung", lambda: time.sleep(30))
    with pytest.warns(ChildRenderDied, match="still running after 1 s: killed"):
        assert in_child(hangs_once, label="the clip", timeout=1.0) == "rendered"
    with pytest.warns(ChildRenderDied), pytest.raises(AssertionError, match="its child died 2 times \\(still running"):
        in_child(lambda: time.sleep(30), label="the clip", timeout=1.0)
