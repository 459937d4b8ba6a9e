"""Renders for the tests, in a forked child of the pytest process.

Blender's Workbench under software OpenGL (Mesa's EGL) has aborted the whole test run once, in a render made in
the pytest process after many that worked (CI, stop 47: SIGABRT in ``bpy.ops.render.render``). So the pytest
process never renders: footage and the review's in-process path run here, in a child forked from a process
without an OpenGL context (where a render works, as ``review.render_guarded``'s does). A child that dies by a
signal or hangs (a fork of a multi-threaded process can deadlock) is tried once more and said so as a warning (the
run's summary lists it, with the end of what the child printed: Blender's own message of why); a second failure
fails the test the same way, an exception in the child fails it with the child's traceback.
"""

import os
import pickle
import select
import signal
import time
import traceback
import warnings

#: Seconds a child may take (the longest test footage renders in about a minute on two cores).
TIMEOUT = 600.0
#: Children a render gets when one dies.
TRIES = 2


class ChildRenderDied(RuntimeWarning):
    """A render's child died by a signal, or hung and was killed, and was tried again."""


def in_child(work, *, label="render", timeout=TIMEOUT, tries=TRIES):
    """``work()``'s return value (picklable), computed in a forked child; see the module's text."""
    from facecap.facecap_addon.render import render_state

    if render_state.STATE["rendered_here"]:
        raise AssertionError("this process has rendered: a forked child's copy of its OpenGL context cannot render")
    deaths = []
    for _ in range(tries):
        status, value = _once(work, timeout)
        if status == "ok":
            return value
        if status == "error":
            raise AssertionError(f"{label} failed in its child:\n{value}")
        deaths.append(value)
        warnings.warn(f"{label}: its child died ({value}); tried again", ChildRenderDied, stacklevel=2)
    raise AssertionError(f"{label}: its child died {len(deaths)} times ({'; '.join(deaths)})")


def _once(work, timeout):
    """("ok", value) | ("error", the child's traceback) | ("died", how (a signal, or killed when it hung), with the
    end of what it printed)."""
    import tempfile

    read, write = os.pipe()
    with tempfile.TemporaryFile() as log:
        pid = os.fork()
        if pid == 0:  # the child: never returns into pytest
            os.close(read)
            try:
                os.dup2(log.fileno(), 1)  # Blender prints from C: kept to say why, should the child die
                os.dup2(log.fileno(), 2)
                try:
                    payload = ("ok", work())
                except BaseException:
                    payload = ("error", traceback.format_exc())
                data = pickle.dumps(payload)
                with os.fdopen(write, "wb") as out:
                    out.write(data)
            finally:
                os._exit(0)
        os.close(write)
        chunks, deadline = [], time.monotonic() + timeout
        try:
            while True:
                left = deadline - time.monotonic()
                if left <= 0 or not select.select([read], [], [], left)[0]:  # a fork can deadlock: tried again
                    os.kill(pid, signal.SIGKILL)
                    os.waitpid(pid, 0)
                    return "died", f"still running after {timeout:.0f} s: killed{_tail(log)}"
                chunk = os.read(read, 1 << 20)
                if not chunk:
                    break
                chunks.append(chunk)
        finally:
            os.close(read)
        _, status = os.waitpid(pid, 0)
        if os.WIFSIGNALED(status):
            return "died", f"signal {signal.Signals(os.WTERMSIG(status)).name}{_tail(log)}"
        if not chunks:
            return "died", f"exit {os.waitstatus_to_exitcode(status)} without a result{_tail(log)}"
    return pickle.loads(b"".join(chunks))


def _tail(log, size=1500):
    """The end of what a child printed, as a suffix of a message (empty when it printed nothing)."""
    log.seek(0, os.SEEK_END)
    log.seek(max(0, log.tell() - size))
    text = log.read().decode("utf-8", "replace").strip()
    return f"; it printed last:\n{text}" if text else ""
