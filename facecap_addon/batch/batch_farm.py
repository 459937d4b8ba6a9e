"""Batches on a Dask distributed cluster: ``python -m facecap batch TAKES --scheduler tcp://host:8786``.

The farm is Dask's (scheduler, workers, placement, retries of lost workers); facecap only submits
one task per take. A task (``farm_take``) runs on a Dask worker and hands its take to a facecap
worker process there (``batch_pool.WorkerProcess``: the same long-lived Blender process and the
same ``batch_worker.run_one`` as a local batch), kept for the next task on that Dask worker. So
Blender never runs inside Dask's worker threads (bpy wants one thread), and a Blender that crashes
or is killed fails its take only: the Dask worker reports it and goes on.

Each Dask worker thread runs one take at a time; start workers with ``--nthreads`` = takes at once
on that node. Paths in the take configs must mean the same files on every node (shared storage).
Install on every node: ``pip install "facecap[farm,blender]"`` (docs/batch.md).
"""

import os
import tempfile
import threading
import time
import uuid
from pathlib import Path

from ...solvers.errors import FacecapError
from ...solvers.tools.batch_summary import iso_time, one_line
from .batch_pool import CANCEL_WAIT, WorkerDied, WorkerProcess, cancelled

#: Seconds to wait for the scheduler's first worker (reaching the scheduler takes Dask's own
#: ``distributed.comm.timeouts.connect``, 30 s unless configured).
WORKERS_TIMEOUT = 120.0

# On a Dask worker: facecap worker processes free for the next take, shared by the worker's threads.
_IDLE = []
_LOCK = threading.Lock()
_STATE = {"count": 0, "logs": None}


def _checkout():
    """An idle facecap worker process of this Dask worker, or a new one."""
    with _LOCK:
        while _IDLE:
            w = _IDLE.pop()
            if w.proc.poll() is None:
                return w
            w.stop(timeout=0.0)
        if _STATE["logs"] is None:
            _STATE["logs"] = Path(tempfile.mkdtemp(prefix="facecap-farm-"))
        _STATE["count"] += 1
        path = _STATE["logs"] / f"worker-{_STATE['count']}.log"
    return WorkerProcess(path, env=node_environment()).start()


def node_environment():
    """The environment a ``retarget`` started by hand on this node has: without the variables Dask's
    nanny adds for its worker processes (``distributed.nanny.pre-spawn-environ``: one OpenBLAS / MKL /
    OpenMP thread, a malloc setting) unless the node was started with them. The BLAS thread count
    changes the last bits of a solve (measured: the sample take's weights CSV differs), and a farm's
    result should be the single run's."""
    import dask  # Dask: only on farm nodes (the "farm" extra)
    from distributed import get_worker  # Dask: only on farm nodes

    env = dict(os.environ)
    if getattr(get_worker(), "nanny", None) is None:  # no nanny: nothing was added
        return env
    try:  # what the nanny was started with (its environment block at exec; Linux)
        raw = Path(f"/proc/{os.getppid()}/environ").read_bytes()
    except OSError:
        return env
    launch = {item.partition(b"=")[0].decode(errors="replace") for item in raw.split(b"\0") if item}
    for key in dask.config.get("distributed.nanny.pre-spawn-environ", {}) or {}:
        if key not in launch:
            env.pop(key, None)
    return env


def farm_take(spec, cancel=None):
    """The Dask task of one take: run it in a facecap worker process on this node; returns its
    record. ``cancel``: the name of the batch's Dask ``Event``; once it is set, a running take is
    interrupted (nothing unfinished is written) and a take not started yet is not started."""
    from distributed import Event, get_worker  # Dask: only on farm nodes (the "farm" extra)

    where = get_worker().address
    event = None if cancel is None else Event(cancel)
    if event is not None and event.is_set():  # the batch was cancelled before this take began
        return dict(cancelled(spec, where), error="not started: the batch was cancelled")
    w = _checkout()
    w.assign(spec)
    try:
        while True:
            if w.replies.poll(0.5):
                kind, payload = w.receive()
                if kind not in ("ready", "started"):
                    break
            elif event is not None and event.is_set():
                w.interrupt()
                event = None  # asked once; its answer follows
    except WorkerDied as death:
        return dict(spec["record"], status="failed", worker=f"{where} ({w.label})", finished=iso_time(time.time()),
                    error=f"{death} while running this take (the other takes go on)")
    if kind == "cancelled":
        w.stop()
        return cancelled(spec, f"{where} ({w.label})")
    w.spec = None
    with _LOCK:
        _IDLE.append(w)
    return dict(payload, worker=f"{where} ({payload.get('worker')})")


class FarmPool:
    """Takes as Dask tasks on the cluster at ``address``; ``run`` reports through ``events`` as
    ``LocalPool.run`` does."""

    def __init__(self, address):
        self.address = address

    def run(self, specs, events):
        try:
            from distributed import Client, Event, as_completed  # the optional "farm" extra
        except ImportError:
            raise FacecapError("--scheduler runs on Dask distributed, which is not installed: "
                               "pip install \"facecap[farm]\"") from None
        try:
            client = Client(self.address, set_as_default=False)
        except (OSError, TimeoutError, ValueError) as exc:
            raise FacecapError(f"cannot reach the Dask scheduler at {self.address}: {one_line(exc)}") from None
        with client:
            try:
                client.wait_for_workers(1, timeout=WORKERS_TIMEOUT)
            except TimeoutError:
                raise FacecapError(f"the Dask scheduler at {self.address} has no workers after {WORKERS_TIMEOUT:g} s "
                                   f"(start `dask worker {self.address}` on the render nodes)") from None
            batch = uuid.uuid4().hex[:12]
            cancel = f"facecap-cancel-{batch}"
            futures = {}
            for i, spec in enumerate(specs):  # in the batch's order: Dask runs earlier submissions first
                key = f"facecap-{batch}-{i}-{spec['record']['take']}"
                futures[client.submit(farm_take, spec, cancel, key=key, pure=False, retries=0)] = spec
            try:
                for future in as_completed(list(futures), loop=client.loop):
                    events.finished(_record(future, futures[future]))
                return True
            except KeyboardInterrupt:
                self._cancel(client, Event(cancel, client=client), futures, events, as_completed)
                return False

    @staticmethod
    def _cancel(client, event, futures, events, as_completed):
        """Stop the batch: running takes are interrupted (the event), queued ones cancelled; the
        running ones' answers are collected (a take that finished meanwhile is kept)."""
        event.set()
        running = {k for keys in client.processing().values() for k in keys}
        waiting = [f for f in futures if not f.done() and f.key not in running]
        client.cancel(waiting)
        busy = [f for f in futures if not f.done() and f.key in running]
        try:
            for future in as_completed(busy, loop=client.loop, timeout=CANCEL_WAIT):
                events.finished(_record(future, futures[future]))
        except (TimeoutError, KeyboardInterrupt):
            pass


def _record(future, spec):
    """A finished future's record; a task that could not run (its Dask worker died every time it
    was tried, or it was lost) is a failed take."""
    try:
        return future.result()
    except Exception as exc:  # Dask's own failures (KilledWorker, CancelledError, ...): this take only
        name = type(exc).__name__
        what = "its Dask worker died each time it ran it" if name == "KilledWorker" else "the farm could not run it"
        return dict(spec["record"], status="failed", finished=iso_time(time.time()),
                    error=one_line(f"{what} ({name}: {exc})"))
