"""A batch worker: one long-lived process with its Blender session, running takes one after another.

Blender starts once (the first ``import bpy``, ~1.5 s, about half of a one-take ``retarget``), and
the characters it samples are kept (``CharacterCache``). Between takes the worker is reset to what
a fresh ``retarget`` sees: each take opens its base .blend again (``headless.run_take``; Blender's
own reset of the scene, 30-50 ms for the sample character), and a kept character is handed out as a
copy, keyed by its file's path, size and modification time, so a take's results are bit-identical
to a single ``retarget`` of it (``tests/e2e/test_batch.py`` compares the weights CSV bytes and the
.blend's solve action).

``serve`` is the worker's main loop (``python -m facecap batch-worker``, started by
``batch_pool.WorkerProcess``); ``run_one`` runs one take and returns its summary record, which is
what both the local pool and a Dask farm (``batch_farm``) call.
"""

import collections
import copy
import os
import socket
import sys
import time
import traceback
from multiprocessing.connection import Connection

from ...solvers.config import load_take_config
from ...solvers.errors import FacecapError
from ...solvers.io.files import write_json_atomic
from ...solvers.tools.batch_summary import iso_time, one_line, result_fields
from ...solvers.tools.report.page import shared_plotly_js
from ...solvers.video.reading import Cancelled
from ..headless.blend_files import start_blender
from ..headless.headless import run_take
from ..render.review import ReviewOptions


class CharacterCache:
    """Characters sampled from .blend files (``Basis`` or ``Target``), kept across takes.

    The key is the .blend's resolved path, size and modification time, the object and the bound
    markers; a changed file is sampled again. ``get`` hands out a deep copy, so nothing a take does
    to its character reaches the next take. At most ``size`` characters are kept (least recently
    used dropped).
    """

    def __init__(self, size=8):
        self.size = size
        self._items = collections.OrderedDict()
        self.hits = self.misses = 0

    def __len__(self):
        return len(self._items)

    def get(self, blend, object_name, marker_names, sample):
        """The character of ``object_name`` in ``blend`` bound to ``marker_names`` (None: not bound);
        ``sample()`` makes it when it is not kept. ``blend`` None (the open file) is never kept."""
        if blend is None:
            return sample()
        try:
            st = os.stat(blend)
        except OSError:
            return sample()
        key = (os.path.realpath(blend), st.st_size, st.st_mtime_ns, object_name,
               None if marker_names is None else tuple(marker_names))
        if key in self._items:
            self._items.move_to_end(key)
            self.hits += 1
        else:
            self.misses += 1
            self._items[key] = sample()
            while len(self._items) > self.size:
                self._items.popitem(last=False)
        return copy.deepcopy(self._items[key])


def run_one(spec, characters=None):
    """Run one take of a batch; returns its summary record (status ``ok`` or ``failed`` with a
    one-line error). ``spec``: {"config", "data", "replace", "overwrite", "record", "done"} (``batch.to_run``;
    ``done``: where its completion is recorded the moment it finishes).
    KeyboardInterrupt (the batch cancelled) is not caught: outputs are atomic, so nothing
    half-written is left; a take that saw the SIGINT between two of its steps (``Cancelled``) is
    stopped the same way."""
    record = dict(spec["record"])
    warnings = []

    def say(message):
        if message.startswith("warning: "):
            warnings.append(message[len("warning: "):])

    t0 = time.perf_counter()
    record.update(status="running", started=iso_time(time.time()), worker=f"{socket.gethostname()} pid {os.getpid()}")
    try:
        config = load_take_config(spec["config"], data=spec["data"])
        # a batch's review pages share one plotly.min.js beside them instead of embedding 4.8 MB each
        review = None if config.output_html is None else \
            ReviewOptions(plotly_js=shared_plotly_js(config.output_html.parent))
        result, outputs = run_take(config, replace=spec.get("replace", False), overwrite=spec.get("overwrite", False),
                                   say=say, characters=characters, review=review)
    except Cancelled as exc:  # SIGINT seen between two steps of a video or rig take: the batch cancelled
        raise KeyboardInterrupt(str(exc)) from exc
    except FacecapError as exc:
        record.update(status="failed", error=one_line(exc))
    except Exception as exc:  # a bug or a broken file deep inside one take must not stop the others
        traceback.print_exc()  # into the worker's log
        record.update(status="failed", error=one_line(f"internal error: {type(exc).__name__}: {exc}"))
    else:
        record.update(status="ok", **result_fields(result, outputs, warnings, {}))
    record["seconds"] = {**record.get("seconds", {}), "total": round(time.perf_counter() - t0, 3)}
    record["finished"] = iso_time(time.time())
    if record["status"] == "ok" and spec.get("done"):
        record_done(spec["done"], record)
    return record


def record_done(path, record):
    """Write a finished take's record to ``path`` at once, atomically: the batch's summary follows a
    moment later, and a batch killed in that moment must not run the take again on ``--resume``."""
    try:
        write_json_atomic(path, record)
    except (FacecapError, OSError) as exc:  # the take itself is done; only --resume loses this shortcut
        record["note"] = one_line(f"its completion record could not be written ({exc})")


def serve(fd_in, fd_out):
    """The worker's loop: start Blender, say ready, then run every take spec received on ``fd_in``
    and send its record on ``fd_out`` until the pipe closes (or None arrives). Returns the exit status:
    0, or 130 when interrupted (SIGINT / SIGTERM: the take running then is reported cancelled)."""
    bpy = start_blender()  # once for every take this worker runs

    requests, replies = Connection(fd_in, writable=False), Connection(fd_out, readable=False)
    replies.send(("ready", {"pid": os.getpid(), "blender": bpy.app.version_string}))
    characters = CharacterCache()
    spec = None
    try:
        while True:
            try:
                spec = requests.recv()
            except EOFError:  # the batch is gone
                return 0
            if spec is None:
                return 0
            replies.send(("started", spec["config"]))
            replies.send(("done", run_one(spec, characters)))
            spec = None
            sys.stdout.flush()
    except KeyboardInterrupt:
        if spec is not None:
            try:
                replies.send(("cancelled", spec["record"]["config"]))
            except OSError:
                pass
        return 130
    finally:
        requests.close()
        replies.close()
