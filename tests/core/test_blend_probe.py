"""The forked child that opens a .blend first (a crash there is one line, not the run's end) never hangs the
run: a child that sleeps without using CPU (Blender's thread pool waits in a forked child for workers it
does not have) is killed and the file opened in the run's own process; a crash and a message still come
back; a child that works slowly is left to work."""

import os
import sys
import time

import pytest

from facecap.facecap_addon.headless import blend_files

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the probe forks only on Linux")


def _fork(child):
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.close(read_end)
        try:
            child(write_end)
        finally:
            os._exit(0)
    os.close(write_end)
    return pid, read_end


def _answer(child, monkeypatch, stuck=1.0):
    monkeypatch.setattr(blend_files, "PROBE_STUCK", stuck)
    pid, fd = _fork(child)
    t0 = time.monotonic()
    try:
        return (*blend_files._child_answer(pid, fd), time.monotonic() - t0, pid)
    finally:
        os.close(fd)


def test_a_child_stuck_without_cpu_is_killed_and_gives_no_answer(monkeypatch):
    message, status, seconds, pid = _answer(lambda fd: time.sleep(60), monkeypatch)
    assert status is None and message == ""
    assert seconds < 10  # PROBE_STUCK 1 s, not the 60 s sleep nor PROBE_TIMEOUT
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)  # killed and reaped


def test_a_failing_child_says_why(monkeypatch):
    def fail(fd):
        os.write(fd, b"Cannot read file: not a blend file")
        os._exit(1)

    message, status, _, _ = _answer(fail, monkeypatch)
    assert status == 1 and message == "Cannot read file: not a blend file"


def test_a_child_that_works_slowly_is_not_stuck(monkeypatch):
    def busy(fd):
        end = time.monotonic() + 2.5  # 2.5 s of CPU, longer than PROBE_STUCK
        while time.monotonic() < end:
            pass

    _, status, seconds, _ = _answer(busy, monkeypatch)
    assert status == 0 and seconds >= 2.4
