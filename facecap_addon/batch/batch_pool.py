"""Batch workers on this machine: long-lived processes (``batch_worker.serve``), one take at a time each.

A worker is a separate process (its own session, so a Ctrl-C in the terminal reaches only the
batch, which then stops the workers in order), started as this checkout's ``cli.py`` run as a
script by the same Python, or inside a Blender by the same Blender binary in the background. Takes
go to it over a pipe and records come back on another one; a worker that dies (SIGKILL, the
out-of-memory killer, a crash in Blender) closes its pipe, its take is reported failed with the
signal, and a new worker takes its place.
"""

import collections
import os
import signal
import socket
import subprocess
import sys
import time
from multiprocessing.connection import Connection, wait
from pathlib import Path

from ...solvers.errors import FacecapError
from ...solvers.tools.batch_summary import iso_time

ROOT = Path(__file__).resolve().parents[2]
#: Seconds a cancelled batch waits for its running takes to stop (they stop between two steps).
CANCEL_WAIT = 60.0
#: Workers that die before they are ready (Blender cannot start) before the batch gives up.
START_FAILURES = 3


class WorkerDied(Exception):
    """The worker process ended without answering; the message says how (signal, exit status)."""


def worker_command():
    """The command line of a worker: the same Blender (in the background) or the same Python, with
    this checkout's ``cli.py`` as a script (so the workers run the code the batch runs)."""
    cli = str(ROOT / "facecap_addon" / "cli.py")
    bpy = sys.modules.get("bpy")
    binary = getattr(getattr(bpy, "app", None), "binary_path", "") if bpy is not None else ""
    if binary and Path(binary).name.lower().startswith("blender"):  # inside a Blender, not the bpy module
        return [binary, "-b", "--python-exit-code", "1", "-P", cli, "--", "batch-worker"]
    return [sys.executable, cli, "--", "batch-worker"]


def describe_exit(returncode):
    if returncode is None:
        return "stopped answering"
    if returncode < 0:
        try:
            name = signal.Signals(-returncode).name
        except ValueError:
            name = "a signal"
        return f"was killed by {name} (signal {-returncode})"
    return f"exited with status {returncode}"


class WorkerProcess:
    """One worker process and its two pipes. ``spec`` is the take it runs (None: idle)."""

    def __init__(self, log_path, command=None, env=None):
        self.log_path = Path(log_path)
        self.command = list(command or worker_command())
        self.env = env  # None: this process's
        self.spec = None
        self.started = False  # whether the worker began ``spec`` (a take not begun goes back to the queue)
        self.ready = False
        self.proc = None
        self.label = None

    def start(self):
        to_r, to_w = os.pipe()
        from_r, from_w = os.pipe()
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        log = open(self.log_path, "ab")
        try:
            self.proc = subprocess.Popen(self.command + ["--fds", f"{to_r},{from_w}"], stdin=subprocess.DEVNULL,
                                         stdout=log, stderr=subprocess.STDOUT, pass_fds=(to_r, from_w),
                                         start_new_session=True, env=self.env)
        except OSError as exc:
            for fd in (to_r, to_w, from_r, from_w):
                os.close(fd)
            raise FacecapError(f"cannot start a batch worker ({' '.join(self.command[:2])}): {exc}") from None
        finally:
            log.close()
        os.close(to_r)  # the worker's ends: the worker holds them now
        os.close(from_w)
        self.requests = Connection(to_w, readable=False)
        self.replies = Connection(from_r, writable=False)
        self.label = f"{socket.gethostname()} pid {self.proc.pid}"
        return self

    @property
    def pid(self):
        return self.proc.pid

    def assign(self, spec):
        """Send ``spec`` to the worker (it runs it once Blender is up). A dead worker's broken pipe is
        seen by the next ``receive``."""
        self.spec, self.started = spec, False
        try:
            self.requests.send(spec)
        except OSError:
            pass

    def receive(self):
        """The next (kind, payload) from the worker: ("ready", info), ("started", config), ("done", record)
        or ("cancelled", config).

        Raises
        ------
        WorkerDied when the worker is gone.
        """
        try:
            message = self.replies.recv()
        except (EOFError, OSError):
            raise WorkerDied(f"the worker process ({self.label}) {describe_exit(self._exit_status())}") from None
        if message[0] == "ready":
            self.ready = True
        elif message[0] == "started":
            self.started = True
        return message

    def _exit_status(self, timeout=10.0):
        try:
            return self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return self.proc.wait()

    def log_tail(self):
        """The last line of the worker's log (why it could not start)."""
        try:
            lines = [line for line in self.log_path.read_text(errors="replace").splitlines() if line.strip()]
        except OSError:
            return ""
        return lines[-1].strip() if lines else ""

    def interrupt(self):
        """Ask the worker to stop its take (SIGINT: its KeyboardInterrupt removes unfinished outputs)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)

    def stop(self, timeout=10.0):
        """End the worker: close its request pipe (it exits), kill it if it does not, and whatever it forked
        that outlived it (its session's process group: a child blocked on a pipe to it would linger)."""
        for conn in (self.requests, self.replies):
            conn.close()
        if self.proc.poll() is None:
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)  # the group outlives its leader while members remain
        except (ProcessLookupError, PermissionError):
            pass  # nothing left of it


class LocalPool:
    """``jobs`` workers on this machine; ``run`` hands out takes and reports through ``events``
    (``started(spec, worker)``, ``finished(record)``, ``tick()``)."""

    def __init__(self, jobs, log_dir, command=None):
        self.jobs = max(1, int(jobs))
        self.log_dir = Path(log_dir)
        self.command = command
        self._count = 0

    def _new_worker(self):
        self._count += 1
        return WorkerProcess(self.log_dir / f"worker-{self._count}.log", self.command).start()

    def run(self, specs, events):
        """Run every spec; returns True, or False when cancelled (KeyboardInterrupt: the running takes
        are stopped, reported ``cancelled`` unless they finished first)."""
        queue = collections.deque(specs)
        workers = []
        try:
            workers = [self._new_worker() for _ in range(min(self.jobs, len(queue)))]
            failures = 0
            while queue or any(w.spec is not None for w in workers):
                for w in workers:
                    if w.spec is None and queue:
                        w.assign(queue.popleft())
                by_conn = {w.replies: w for w in workers}
                for conn in wait(list(by_conn), timeout=1.0):
                    w = by_conn[conn]
                    try:
                        kind, payload = w.receive()
                    except WorkerDied as death:
                        failures = self._replace(w, death, workers, queue, events, failures)
                        continue
                    if kind == "started":
                        events.started(w.spec, w.label)
                    elif kind == "done":
                        w.spec = None
                        events.finished(payload)
                for w in [w for w in workers if w.proc.poll() is not None]:
                    # dead, but its pipe still open: a process it forked (a split solve) outlived it
                    death = WorkerDied(f"the worker process ({w.label}) {describe_exit(w.proc.returncode)}")
                    failures = self._replace(w, death, workers, queue, events, failures)
                events.tick()
            return True
        except KeyboardInterrupt:
            self._cancel(workers, events)
            return False
        finally:
            for w in workers:
                w.stop()

    def _replace(self, w, death, workers, queue, events, failures):
        """A worker died: its take failed (or, when it had not begun it, goes back to the queue); a new
        worker takes its place. Returns the count of workers that died before they were ready."""
        workers.remove(w)
        w.stop(timeout=0.0)
        if not w.ready:
            failures += 1
            if failures >= START_FAILURES:
                tail = w.log_tail()
                raise FacecapError(f"batch workers cannot start: {death}" + (f"; its log ends: {tail}" if tail else ""))
        if w.spec is not None and not w.started:
            queue.appendleft(w.spec)
        elif w.spec is not None:
            events.finished(dict(w.spec["record"], status="failed", worker=w.label, finished=iso_time(time.time()),
                                 error=f"{death} while running this take (the other takes go on)"))
        if queue:
            workers.append(self._new_worker())
        return failures

    def _cancel(self, workers, events):
        """Stop the running takes: SIGINT each busy worker and collect its answer (a take that
        finished meanwhile is kept); a second Ctrl-C or ``CANCEL_WAIT`` seconds kill the rest."""
        busy = {w.replies: w for w in workers if w.spec is not None}
        for w in busy.values():
            w.interrupt()
        deadline = time.monotonic() + CANCEL_WAIT
        try:
            while busy and time.monotonic() < deadline:
                for conn in wait(list(busy), timeout=0.5):
                    w = busy[conn]
                    try:
                        kind, payload = w.receive()
                    except WorkerDied:
                        kind, payload = "cancelled", None
                    if kind in ("ready", "started"):
                        continue
                    del busy[conn]
                    if kind == "done" or w.started:  # a take not begun stays queued: "not started"
                        events.finished(payload if kind == "done" else cancelled(w.spec, w.label))
        except KeyboardInterrupt:
            pass
        for w in busy.values():
            w.proc.kill()
            if w.started:
                events.finished(cancelled(w.spec, w.label))


def cancelled(spec, worker=None):
    """The record of a take stopped while it ran: what it had not finished writing was not written."""
    return dict(spec["record"], status="cancelled", worker=worker, finished=iso_time(time.time()),
                error="cancelled while running; outputs it had not finished were not written")
