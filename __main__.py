"""``python -m facecap <command>``: the headless command line (see facecap_addon/cli.py).

Ctrl-C or SIGTERM at any moment ends the run with one line and exit status 130: while the modules
load (before the command line's own handling starts) and after the command has finished (when
nothing is left to stop) as well, and also when the process was started with SIGINT ignored (a
background job of a shell script). Blender's temporary folder goes with every exit, an interrupted
one included (it leaves at once, without the exit handlers that remove it otherwise).
"""

import os
import shutil
import signal
import sys


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def _run():
    signal.signal(signal.SIGTERM, _interrupt)  # as Ctrl-C: the same clean stop
    signal.signal(signal.SIGINT, signal.default_int_handler)  # even when started with it ignored
    try:
        from .facecap_addon.headless import console

        console.lost_interrupts_redelivered()  # a Ctrl-C inside an import's module lock is not lost
        from .facecap_addon.cli import main  # numpy and the solvers load here

        status = main(sys.argv[1:])
    except KeyboardInterrupt:
        print("facecap: interrupted; nothing unfinished was written", file=sys.stderr)
        status = 130
    for sig in (signal.SIGINT, signal.SIGTERM):  # finished: a late signal must not cut the exit in half
        signal.signal(sig, signal.SIG_IGN)
    return status


def _exit(status):
    """Exit with ``status``. After an interrupt, at once: an interrupt that landed in code a module ran at
    its import (Python notes it for good) would otherwise turn the exit into death by SIGINT."""
    if status == 130:
        _remove_blender_tempdir()
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(130)
    sys.exit(status)


def _remove_blender_tempdir():
    """Blender's session folder (``$TMPDIR/blender_XXXXXX``), which its exit handlers would remove."""
    bpy = sys.modules.get("bpy")
    try:
        folder = bpy.app.tempdir if bpy is not None else ""
    except Exception:  # noqa: BLE001 - a Blender half started: nothing of its to remove
        return
    if folder and os.path.basename(os.path.normpath(folder)).startswith("blender_"):
        shutil.rmtree(folder, ignore_errors=True)


_exit(_run())
