"""``python -m facecap <command>``: the headless command line (see facecap_addon/cli.py).

Ctrl-C or SIGTERM at any moment ends the run with one line and exit status 130: while the modules
load (before the command line's own handling starts) and after the command has finished (when
nothing is left to stop) as well.
"""

import os
import signal
import sys


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def _run():
    signal.signal(signal.SIGTERM, _interrupt)  # as Ctrl-C: the same clean stop
    try:
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
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(130)
    sys.exit(status)


_exit(_run())
