"""Two halves of a long take's windows solved at the same time: one half in a forked child process,
one here (and, with ``run_beside``, any two independent jobs: the CLI reads the take while Blender
starts). Results come back with their arrays out of band (no pickled copy of them).

The temporal kernel's banded LAPACK calls go through scipy's wrappers, which hold the GIL, so
threads cannot overlap them; a forked child can, and it inherits the inputs without a copy (only
its result comes back through a pipe). Fork is used only where it is the platform's safe default
(Linux) and not inside an interactive Blender session (a GUI process should not be forked); else,
or if the child fails, both halves run here one after the other. Same results either way.
"""

import ctypes
import multiprocessing as mp
import os
import pickle
import signal
import sys
import threading


def fork_available():
    """True where ``run_pair`` can put the second half in a child process."""
    if not sys.platform.startswith("linux") or not hasattr(os, "fork"):
        return False
    if len(os.sched_getaffinity(0)) < 2:  # the cores this process may run on, not the machine's
        return False
    bpy = sys.modules.get("bpy")  # read only: solvers never import bpy
    return bpy is None or bool(getattr(getattr(bpy, "app", None), "background", True))


class HeldInterrupts:
    """SIGINT and SIGTERM only noted from ``hold()`` to ``release()``: a fork runs Python's at-fork handlers
    (logging's lock release among them), and a KeyboardInterrupt raised inside one is printed as a traceback
    and lost. ``release()`` puts the handlers back and raises KeyboardInterrupt if a signal came; a forked
    child calls ``restore()`` (the handlers back, nothing raised). Off the main thread it does nothing."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self):
        self.came, self.previous = [], None

    def hold(self):
        if threading.current_thread() is threading.main_thread():
            self.previous = {sig: signal.signal(sig, lambda signum, frame: self.came.append(signum))
                             for sig in self.SIGNALS}
        return self

    def restore(self):
        if self.previous is not None:
            for sig, handler in self.previous.items():
                signal.signal(sig, handler)
            self.previous = None

    def release(self):
        self.restore()
        if self.came:
            self.came.clear()
            raise KeyboardInterrupt


def run_pair(fn, first, second):
    """``(fn(*first), fn(*second))``, the second computed in a forked child when possible."""
    return run_beside(lambda: fn(*first), lambda: fn(*second))


def run_beside(here, there, *, let_finish=False):
    """``(here(), there())`` with ``there`` run in a forked child meanwhile, when possible.

    ``there()``'s result comes back pickled. If the child fails, ``there()`` runs here after
    ``here()`` (so its errors are raised here, with their messages). If ``here()`` raises, the child
    is killed, or, with ``let_finish``, waited for (a child writing a file then completes its
    atomic write instead of leaving a temporary file behind).
    """

    if not fork_available():
        return here(), there()
    release_freed_memory()  # pages the allocator kept would count in both processes
    ctx = mp.get_context("fork")
    recv, send = ctx.Pipe(duplex=False)

    held = HeldInterrupts()

    def child():
        held.restore()
        try:
            out = ("ok", there())
        except BaseException as e:  # the parent then runs it itself
            out = ("error", repr(e))
        release_freed_memory()  # what ``there`` freed, while the parent takes the result
        _send(send, out)

    held.hold()
    try:
        proc = ctx.Process(target=child, daemon=True)
        proc.start()
    except OSError:
        recv.close()
        send.close()
        held.release()
        return here(), there()
    except BaseException:
        held.restore()
        raise
    send.close()  # so that recv() ends with EOFError if the child dies without an answer
    done = False
    try:
        held.release()  # a Ctrl-C that came while the child started: raised here, where the child is ended
        a = here()
        try:
            status, b = _recv(recv)
        except EOFError:
            status, b = "error", None
        done = True
    finally:
        if not done and let_finish:
            try:
                _recv(recv)
            except EOFError:
                pass
            done = True
        recv.close()
        if done:
            proc.join(timeout=10.0)  # it exits right after sending
        if proc.is_alive():
            proc.kill()
        proc.join()
    if status != "ok":
        b = there()
    return a, b


def _send(conn, obj):
    """Send ``obj`` with its large buffers (numpy arrays) out of band: written from where they are,
    not copied into one pickle first (a long take's markers are 587 MB)."""
    buffers = []
    head = pickle.dumps(obj, protocol=5, buffer_callback=buffers.append)
    views = [b.raw() for b in buffers]
    conn.send((head, [v.nbytes for v in views]))
    for v in views:
        conn.send_bytes(v)


def _recv(conn):
    """The object ``_send`` sent: its buffers read straight into the arrays' memory."""
    head, sizes = conn.recv()
    buffers = []
    for n in sizes:
        buf = bytearray(n)
        if n:
            conn.recv_bytes_into(buf)
        else:
            conn.recv_bytes()
        buffers.append(buf)
    return pickle.loads(head, buffers=buffers)


#: Takes at least this long give freed memory back between the stages of a solve too
#: (``release_freed_memory(frames)``): there it is GBs, and re-faulting it a small part of the time.
LONG_TAKE_FRAMES = 100_000


def release_freed_memory(frames=None):
    """Give the memory the C allocator keeps after frees back to the system (glibc's
    ``malloc_trim``; a no-op elsewhere). Batch commands keep freed memory for reuse while they
    compute (``facecap_addon.cli.keep_freed_memory``); between stages whose working sets differ
    (reading, solving, keying) that memory is only weight: measured after the 36,000-frame CLI
    solve, 1.33 -> 0.88 GB resident. With ``frames`` (the take's length), only on takes of at least
    ``LONG_TAKE_FRAMES``. Returns whether it ran."""
    global _TRIM
    if frames is not None and frames < LONG_TAKE_FRAMES:
        return False
    if _TRIM is None:
        _TRIM = False
        if sys.platform.startswith("linux"):
            try:
                _TRIM = ctypes.CDLL("libc.so.6").malloc_trim
            except (OSError, AttributeError):
                pass
    if not _TRIM:
        return False
    _TRIM(0)
    return True


_TRIM = None
