""".blend files of a headless run: opened so that a damaged file is one line, saved atomically, and
stamped with the character they were made from.

Opening (``open_blend``): ``solvers.io.blend_file`` first looks at the file's structure (not a .blend,
cut short); then, headless on Linux, a forked child opens it first, so a file that makes Blender fail
or crash ends the child, not the run, and the run says so in one line; only then does the run open it.

Saving (``save_blend_atomic``): to a temporary file beside the output, renamed into place; a full disk
or a permission problem is one ``OutputError``.

The character (``stamp_target`` / ``target_changed``): the output .blend records the ``[target] blend``
it was made from (size, time and SHA-256), so a later run adding to it can say when that character has
changed since (the run adds to the output's own copy of it; ``--replace`` starts from the new one).
"""

import contextlib
import os
import select
import signal
import sys
import time
from pathlib import Path

from ...solvers.engine.split import HeldInterrupts
from ...solvers.errors import InputFileError
from ...solvers.io.blend_file import check_blend_structure
from ...solvers.io.files import atomic_path, file_sha256
from ...solvers.io.outputs import write_error
from . import console

#: Seconds the forked child may take to open a file before the run gives up on it.
PROBE_TIMEOUT = 600.0
#: Seconds a forked child may sleep without using any CPU before it counts as stuck: a child forked after
#: Blender's thread pool (TBB) started can wait forever for workers it does not have. The file is then
#: opened in this process, as where no child can be forked.
PROBE_STUCK = 10.0
#: The scene property holding the character an output .blend was made from
TARGET_STAMP = "facecap_target_blend"
#: Files this process opened successfully already (path, size, mtime): not probed again (a batch worker
#: opens the same character for every take).
_PROBED = set()


def start_blender():
    """``import bpy`` (Blender starts on the first one) with Ctrl-C and SIGTERM held back until it is up:
    a start-up cut in half leaves a Blender that crashes at exit. A signal that came meanwhile is raised
    as KeyboardInterrupt once Blender is up. Returns the ``bpy`` module."""
    if "bpy" in sys.modules:
        return sys.modules["bpy"]
    with interrupts_deferred():
        import bpy  # bpy: Blender starts here, with the signals held back
    return bpy


@contextlib.contextmanager
def interrupts_deferred():
    """Within the block SIGINT and SIGTERM only note that they came; after it, KeyboardInterrupt is
    raised if one did. Off the main thread (no signals there) the block just runs."""
    held = HeldInterrupts().hold()
    try:
        yield
    except BaseException:
        held.restore()
        raise
    held.release()


def open_blend(path, what):
    """Open ``path`` in this Blender (``bpy.ops.wm.open_mainfile``) or raise InputFileError naming it.

    what : what the file is, for the message ("the [target] blend")
    """
    import bpy  # bpy: Blender starts on first import

    check_blend_structure(path, what)
    why = _probe(path)
    if why is not None:
        raise InputFileError(path, f"Blender cannot read this .blend ({what}): {why}")
    try:
        # Held back while it loads: Ctrl-C inside a load handler (Cycles' version update) would print that
        # handler's traceback; it is raised once the file is open.
        with interrupts_deferred():
            bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False)
    except RuntimeError as exc:
        raise InputFileError(path, f"Blender cannot read this .blend ({what}): {_first_line(exc)}") from None


def _first_line(exc):
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    return (lines[0] if lines else type(exc).__name__).removeprefix("Error: ")


def _probe(path):
    """Why a forked child could not open ``path`` (None: it could, or no child can be forked here)."""
    import bpy  # bpy: Blender starts on first import

    if not (sys.platform.startswith("linux") and bpy.app.background and hasattr(os, "fork")):
        return None
    try:
        st = os.stat(path)
    except OSError:
        return None  # the open says why
    key = (os.path.realpath(path), st.st_size, st.st_mtime_ns)
    if key in _PROBED:
        return None
    read_end, write_end = os.pipe()
    held = HeldInterrupts().hold()  # a Ctrl-C inside the fork's handlers would be printed and lost
    try:
        pid = os.fork()
    except BaseException:
        held.restore()
        raise
    if pid == 0:  # the child: open, say how it went, leave without Blender's exit handlers
        os.close(read_end)
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_DFL)
        status = 0
        try:
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, 1)
            os.dup2(null, 2)
            bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False)
        except BaseException as exc:  # noqa: BLE001 - everything the child meets is the parent's message
            os.write(write_end, _first_line(exc).encode("utf-8", "replace")[:2000])
            status = 1
        os._exit(status)
    os.close(write_end)
    try:
        message, status = _child_answer(pid, read_end, held)
    finally:
        os.close(read_end)
    if status is None:  # stuck, not crashed: no answer about the file
        console.log.debug(f"the child opening {path} made no progress for {PROBE_STUCK:g} s; opened here")
        return None
    if status == 0:
        _PROBED.add(key)
        return None
    if status < 0:
        try:
            name = signal.Signals(-status).name
        except ValueError:
            name = f"signal {-status}"
        if -status in (signal.SIGINT, signal.SIGTERM):
            raise KeyboardInterrupt
        return f"Blender crashed reading it ({name}); the file is damaged"
    return message or "Blender failed reading it"


def _child_answer(pid, fd, held=None):
    """(the child's message, its exit status: negative for the signal that ended it, None when it was stuck
    (asleep without using any CPU for ``PROBE_STUCK`` seconds) and was killed); killed too after
    ``PROBE_TIMEOUT``."""
    chunks, open_pipe = [], True
    deadline = time.monotonic() + PROBE_TIMEOUT
    cpu, still_since = _cpu_ticks(pid), time.monotonic()
    try:
        if held is not None:
            held.release()  # a Ctrl-C that came during the fork: raised here, where the child is ended
        while True:
            if open_pipe and select.select([fd], [], [], 0.05)[0]:
                chunk = os.read(fd, 4096)
                chunks.append(chunk)
                open_pipe = bool(chunk)
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                while open_pipe and (chunk := os.read(fd, 4096)):
                    chunks.append(chunk)
                message = b"".join(chunks).decode("utf-8", "replace").strip()
                return message, os.waitstatus_to_exitcode(status)
            now, used = time.monotonic(), _cpu_ticks(pid)
            if used != cpu or used is None or _state(pid) != "S":  # working, waiting for the disk or a core
                cpu, still_since = used, now
            if now - still_since > PROBE_STUCK:
                _kill(pid)
                return "", None
            if now > deadline:
                os.kill(pid, signal.SIGKILL)
            if not open_pipe:
                time.sleep(0.01)
    except BaseException:
        _kill(pid)
        raise


def _stat(pid):
    """The fields of /proc/<pid>/stat after the command name (Linux; None elsewhere)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None


def _cpu_ticks(pid):
    """User + system CPU clock ticks of process ``pid`` so far (None where /proc cannot tell)."""
    fields = _stat(pid)
    try:
        return int(fields[11]) + int(fields[12])
    except (TypeError, IndexError, ValueError):
        return None


def _state(pid):
    """The process state letter: S sleeping, R running or runnable, D waiting for the disk, ..."""
    fields = _stat(pid)
    return fields[0] if fields else None


def _kill(pid):
    with contextlib.suppress(OSError):
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)


def save_blend_atomic(path):
    """Save the open file as ``path`` (compressed) through a temporary file beside it; a failed save
    (a full disk, permissions) is an OutputError naming ``path`` and leaves ``path`` as it was."""
    import bpy  # bpy: Blender starts on first import

    try:
        with atomic_path(path, suffix=".blend") as tmp:
            tmp.unlink()  # a name only: over an existing file Blender would keep a .blend1 backup of it
            try:
                with _unevaluated_save_context(bpy):
                    bpy.ops.wm.save_as_mainfile(filepath=str(tmp), copy=True, compress=True)
            finally:
                with contextlib.suppress(OSError):
                    Path(f"{tmp}@").unlink()  # Blender's own partial file, left when the save failed
    except (OSError, RuntimeError) as exc:
        raise write_error(path, exc) from None


@contextlib.contextmanager
def _unevaluated_save_context(bpy):
    """The save's context: a scene of its own with no users when the file has one scene.

    An operator call first evaluates its context's view layer, and that copies every keyed action
    for evaluation: on a 100-minute take about 1.2 GiB beside the 1.15 GiB of keys (measured at
    120,000 frames: +0.41 GiB at the save, +0.003 GiB with this context). A scene without users is
    not written, so the file is the same. Only with one scene: the file then opens on it as before
    (with several it would open on the first one, not necessarily the active one).
    """
    scenes = bpy.data.scenes
    if len(scenes) != 1:
        yield
        return
    context = scenes.new("facecap save context")
    context.user_clear()  # not written into the file
    try:
        with bpy.context.temp_override(scene=context, view_layer=context.view_layers[0]):
            yield
    finally:
        context.use_fake_user = True  # a user for the removal to take (Blender 4.2-4.5 report a bad count otherwise)
        scenes.remove(context)


def remove_earlier_solve(name):
    """Remove the solve action ``name`` (and its head action) an earlier run of this take keyed into the
    open file, so that a re-run (``batch --resume`` after a kill, a retarget run again) replaces its
    own action instead of adding ``name.001``. Returns the removed actions' names."""
    import bpy  # bpy: Blender starts on first import

    from ..scene.layers import SOLVE_TAG  # loads bpy

    action = bpy.data.actions.get(name)
    if action is None or action.library is not None or action.get(SOLVE_TAG) != name:
        return []  # not a solve of this take: the new action gets a name of its own
    removed = [name]
    head = bpy.data.actions.get(f"{name} Head")
    bpy.data.actions.remove(action)
    if head is not None and head.library is None:
        bpy.data.actions.remove(head)
        removed.append(f"{name} Head")
    return removed


def file_stamp(path):
    """{"path", "size", "sha256"} of ``path``."""
    return {"path": str(path), "size": os.path.getsize(path), "sha256": file_sha256(path)}


def stamp_target(target):
    """Record on the open file's scene (saved with the output .blend) the ``[target] blend`` it was made from."""
    import bpy  # bpy: Blender starts on first import

    if target is not None and Path(target).is_file():
        stamp = file_stamp(target)
        bpy.context.scene[TARGET_STAMP] = f"{stamp['sha256']} {stamp['size']} {stamp['path']}"


def target_changed(target):
    """A warning when the output .blend open now was made from another version of ``target`` (the
    ``[target] blend``) than the one on disk, else None."""
    import bpy  # bpy: Blender starts on first import

    recorded = bpy.context.scene.get(TARGET_STAMP)
    if not isinstance(recorded, str) or target is None or not Path(target).is_file():
        return None
    digest = recorded.split(" ", 1)[0]
    if file_stamp(target)["sha256"] == digest:
        return None
    return (f"[target] blend {target} has changed since the output .blend was made from it: this run adds to "
            "the output's own copy of the character; run with --replace to start from the changed one")


def names_in_file(target_object):
    """What a take config may name in the open .blend (``solvers.config.names.check_scene_names``): every
    object's name and type, the shape keys of ``target_object`` (None when it has none) and a function
    giving an armature's bones."""
    import bpy  # bpy: Blender starts on first import

    obj = bpy.data.objects.get(target_object)
    keys = getattr(getattr(obj, "data", None), "shape_keys", None)
    shapes = None if keys is None else [k.name for k in keys.key_blocks if k != keys.reference_key]

    def bones_of(name):
        armature = bpy.data.objects.get(name)
        return [b.name for b in armature.data.bones] if armature is not None and armature.type == "ARMATURE" else []

    return {o.name: o.type for o in bpy.data.objects}, shapes, bones_of
