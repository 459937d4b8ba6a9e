"""What the command line prints, and where.

* Messages go through :mod:`logging` under the package's logger (``facecap``; inside Blender
  ``bl_ext.<repo>.facecap``), one line each on stderr: ``facecap: <progress>``, ``facecap: warning: ...``.
  ``--quiet`` keeps warnings and errors, ``--verbose`` adds the debug lines (Blender's own among them).
* A command's product (a table, a summary, ``inspect``'s description, the paths written) goes to stdout
  with ``print``: it is what a script pipes on, and ``--quiet`` does not hide it.
* Blender writes its own lines (``Read blend: ...``, ``Info: Saved copy as ...``) from C straight to file
  descriptor 1. :func:`blender_output_captured` points that descriptor at a pipe whose lines become debug
  messages, while Python's ``sys.stdout`` keeps writing to the real stdout.
* A Python warning is one line, ``facecap: warning: <message>`` (where it came from only with ``--verbose``).
"""

import contextlib
import ctypes
import logging
import os
import re
import signal
import sys
import tempfile
import threading
import warnings

from ...solvers.errors import FacecapError

#: The package's top-level name: ``facecap``, or ``bl_ext.<repo>.facecap`` inside Blender.
PACKAGE = __name__.rsplit(".", 3)[0]  # facecap (or bl_ext.<repo>.facecap in a Blender)
log = logging.getLogger(PACKAGE)
#: Blender's own output lines, shown with ``--verbose``.
blender_log = logging.getLogger(PACKAGE + ".blender")
#: --quiet, default, --verbose
LEVELS = {-1: logging.WARNING, 0: logging.INFO, 1: logging.DEBUG}
PREFIX = {logging.DEBUG: "debug: ", logging.WARNING: "warning: ", logging.ERROR: "error: ", logging.CRITICAL: "error: "}


class LineFormatter(logging.Formatter):
    """``facecap: [warning: ]<message>`` on one line; Blender's lines as ``blender: <line>``."""

    def format(self, record):
        message = " ".join(record.getMessage().split("\n"))
        if record.name == blender_log.name:
            return f"blender: {message}"
        return f"facecap: {PREFIX.get(record.levelno, '')}{message}"


class StderrHandler(logging.StreamHandler):
    """Writes to whatever ``sys.stderr`` is when a message is emitted (a test's capture, a redirect)."""

    def __init__(self):
        super().__init__(sys.stderr)

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value):  # StreamHandler.__init__ sets it; the property always answers sys.stderr
        pass


def configure(verbosity=0):
    """Set up the package's logger for a command: ``verbosity`` -1 (--quiet), 0, 1 (--verbose).
    Called once per command; calling again replaces the handler (tests run many commands in one process)."""
    level = LEVELS[max(-1, min(1, verbosity))]
    for handler in [h for h in log.handlers if isinstance(h, StderrHandler)]:
        log.removeHandler(handler)
    handler = StderrHandler()
    handler.setFormatter(LineFormatter())
    log.addHandler(handler)
    log.setLevel(level)
    log.propagate = False
    warnings.showwarning = show_warning
    return level


def verbosity(args):
    """-1, 0 or 1 from parsed ``--quiet`` / ``--verbose``."""
    return -1 if getattr(args, "quiet", False) else 1 if getattr(args, "verbose", False) else 0


def show_warning(message, category, filename, lineno, file=None, line=None):
    """``warnings.showwarning`` for the command line: the message on one line, where it came from at debug level."""
    log.warning(str(message))
    log.debug(f"(the warning above: {category.__name__} at {filename}:{lineno})")


def quiet():
    """Whether progress is hidden (``--quiet``)."""
    return not log.isEnabledFor(logging.INFO)


#: Where a command's product goes while Blender's output is captured (see ``stdout``).
_products = []


def stdout():
    """The stream for a command's product (``print(..., file=console.stdout())``): the real stdout even
    while :func:`blender_output_captured` sends everything else written to stdout to the debug log."""
    return _products[-1] if _products else sys.stdout


@contextlib.contextmanager
def blender_output_captured():
    """Within the block, whatever is written to stdout becomes debug lines of ``blender_log``: by C code
    (Blender's ``Read blend: ...``) and child processes to file descriptor 1, and by Python to ``sys.stdout``
    (Blender prints an operator's reports there: ``Info: Saved copy as ...``). A command's own product
    goes to :func:`stdout`, the stdout in place before the block."""
    try:
        sys.stdout.flush()
        _flush_c_stdio()
        real = os.dup(1)
    except (OSError, ValueError, AttributeError):  # no file descriptor 1 (a GUI without a console)
        yield
        return
    read_end, write_end = os.pipe()
    os.dup2(write_end, 1)
    os.close(write_end)
    reader = threading.Thread(target=_log_lines, args=(read_end,), name="blender output", daemon=True)
    reader.start()
    python_stdout = sys.stdout
    encoding = getattr(python_stdout, "encoding", None) or "utf-8"
    product = (os.fdopen(os.dup(real), "w", encoding=encoding, errors="backslashreplace", buffering=1)
               if _is_fd1(python_stdout) else python_stdout)  # a test's capture object stays the product's
    sys.stdout = os.fdopen(os.dup(1), "w", encoding="utf-8", errors="backslashreplace", buffering=1)
    _products.append(product)
    try:
        yield
    finally:
        _products.pop()
        try:
            sys.stdout.close()
            if product is not python_stdout:
                product.close()
        finally:
            sys.stdout = python_stdout
            _flush_c_stdio()  # Blender's printf lines still in C's buffer belong to the pipe
            os.dup2(real, 1)  # the pipe's last writer here is closed: the reader sees its end
            os.close(real)
        reader.join(timeout=5)  # a forked child still holding the pipe would keep it open


def _flush_c_stdio():
    """``fflush(NULL)``: C's stdout buffer (full buffering on a pipe) written out now."""
    try:
        libc = ctypes.CDLL(None) if os.name != "nt" else ctypes.cdll.msvcrt
        libc.fflush(None)
    except (OSError, AttributeError, TypeError):
        pass


def _is_fd1(stream):
    try:
        return stream.fileno() == 1
    except (AttributeError, OSError, ValueError):
        return False


#: The first line of Blender's report on a driver it could not run (C code, file descriptor 2), and the
#: lines that follow it: the target, blank lines, a syntax error's excerpt.
_DRIVER_ERROR = re.compile(r"^\s*(BPY_driver_exec:|Error in PyDriver:)")
_DRIVER_MORE = re.compile(r"^(\s*$|For target:|  File \"<bpy driver>\"|    |\w*Error: )")


@contextlib.contextmanager
def driver_errors_to_debug():
    """Within the block (a .blend's load and the depsgraph's first update: where Blender evaluates a
    driver for the first time, and reports one that cannot run, once), Blender's own lines about such
    drivers become debug lines of ``blender_log`` (``--verbose`` shows them; facecap names those
    drivers once itself, ``rig.drivers``); anything else written to stderr is written there after."""
    try:
        sys.stderr.flush()
        _flush_c_stdio()
        real = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no file descriptor 2
        yield
        return
    with tempfile.TemporaryFile() as held:
        os.dup2(held.fileno(), 2)
        try:
            yield
        finally:
            try:
                sys.stderr.flush()
            except (OSError, ValueError):
                pass
            _flush_c_stdio()
            os.dup2(real, 2)
            os.close(real)
            held.seek(0)
            _sort_stderr(held.read().decode("utf-8", "backslashreplace").splitlines(keepends=True))


def _sort_stderr(lines):
    """Blender's driver reports to the debug log, the rest back to stderr (in order)."""
    block, rest = False, []
    for line in lines:
        block = bool(_DRIVER_ERROR.match(line)) or (block and bool(_DRIVER_MORE.match(line)))
        if block:
            if line.strip():
                blender_log.debug(line.rstrip())
        else:
            rest.append(line)
    if rest:
        sys.stderr.write("".join(rest))
        sys.stderr.flush()


def _log_lines(fd):
    with open(fd, "rb", closefd=True) as pipe:
        for raw in pipe:
            line = raw.decode("utf-8", "backslashreplace").rstrip()
            if line:
                blender_log.debug(line)


@contextlib.contextmanager
def closed_pipe_ends_quietly():
    """``facecap inspect --json | head``: when the reader of stdout goes away, stop without a traceback.
    Raises ``SystemExit(141)`` (a shell's status for a process ended by SIGPIPE)."""
    try:
        yield
        sys.stdout.flush()
    except BrokenPipeError:
        # Python flushes stdout again at exit: point it at devnull so that flush cannot fail too
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, sys.stdout.fileno())
        except (OSError, ValueError):
            pass
        raise SystemExit(141) from None


def failed(exc):
    """Say why a command failed and return its exit status, 1: a project error's message (a config's
    problems one line each), what the system refused (a file, the memory), or a bug as an internal error
    (``FACECAP_TRACEBACK=1`` shows where); never a traceback."""
    if isinstance(exc, FacecapError):
        for line in str(exc).splitlines():
            log.error(line)
    elif isinstance(exc, OSError):
        log.error((f"{exc.filename}: " if getattr(exc, "filename", None) else "") + str(exc.strerror or exc))
    elif isinstance(exc, MemoryError):
        log.error("out of memory (what this command reads or makes is too large for this machine's memory)")
    else:
        text = " ".join(str(exc).split())[:300]
        log.error(f"internal error (a bug in facecap; run with FACECAP_TRACEBACK=1 for where): "
                  f"{type(exc).__name__}: {text}")
    return 1


def _interrupt(signum, frame):
    raise KeyboardInterrupt


#: How long after an interrupt Python swallowed it is delivered again (seconds).
REDELIVERY_DELAY = 0.05


def lost_interrupts_redelivered():
    """Install a ``sys.unraisablehook`` for the KeyboardInterrupt a signal raises where Python cannot pass it
    on (a weakref callback such as the import system's module locks, a ``__del__``): Python prints it as
    "Exception ignored in ..." with a traceback and runs on as if no Ctrl-C came. The hook prints nothing and
    sends SIGINT to the main thread again a moment later, when it lands in ordinary code. Other unraisable
    exceptions go to the hook that was there. Installed once; safe to call again."""
    if getattr(sys.unraisablehook, "facecap_redelivers", False):
        return
    previous = sys.unraisablehook

    def hook(unraisable):
        if not issubclass(unraisable.exc_type, KeyboardInterrupt):
            previous(unraisable)
            return
        timer = threading.Timer(REDELIVERY_DELAY, _redeliver, (threading.main_thread().ident,))
        timer.daemon = True
        timer.start()

    hook.facecap_redelivers = True
    sys.unraisablehook = hook


def _redeliver(main_ident):
    if callable(signal.getsignal(signal.SIGINT)):  # not once the run is over (ignored then)
        signal.pthread_kill(main_ident, signal.SIGINT)


def interrupts_handled():
    """Make Ctrl-C (SIGINT) and SIGTERM raise KeyboardInterrupt in the main thread, whatever they did before:
    a process started with SIGINT ignored (a background job of a shell script) would otherwise stop only where
    facecap holds signals itself, and run on to the end elsewhere (while Blender opens a .blend). Returns the
    handlers replaced, for ``restore_handlers`` (None off the main thread, where signals cannot be handled)."""
    if threading.current_thread() is not threading.main_thread():
        return None
    lost_interrupts_redelivered()
    # Python writes, then removes, a probe file in $TMPDIR the first time it needs its temporary folder: a Ctrl-C
    # between the two (the .blend opening) left the probe behind. Found now, while the signals still do as before.
    tempfile.gettempdir()
    return {signal.SIGINT: signal.signal(signal.SIGINT, signal.default_int_handler),
            signal.SIGTERM: signal.signal(signal.SIGTERM, _interrupt)}


def restore_handlers(previous):
    for sig, handler in (previous or {}).items():
        signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
