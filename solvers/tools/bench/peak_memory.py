"""Peak memory of a command's whole process tree (Linux ``/proc``), for the memory benchmark.

A watcher thread samples, every ``interval`` seconds, every process descended from the command
(found by parent ids: forked children that solve half a take or write a file beside the main
process) and sums their resident set sizes. Two sums are kept:

- RSS: what ``top`` shows per process, summed. A forked child's pages shared copy-on-write with
  its parent count twice, so this over-states what the tree takes from the machine.
- PSS: shared pages divided among the processes sharing them (``/proc/PID/smaps_rollup``): the
  memory the tree really occupies. Costlier to read, so it is sampled every ``pss_every``-th time.

The main process's own peak is exact (the kernel's high-water mark, ``ru_maxrss`` from ``wait4``).
Lines the command writes to stderr that start with ``stage_prefix`` (the CLI's ``facecap: [3/5]
solving ...``) name the stage each sample is attributed to.
"""

import os
import re
import subprocess
import threading
import time

PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def available():
    """True where process trees can be sampled (Linux /proc)."""
    return os.path.isfile("/proc/self/statm") and os.path.isfile("/proc/self/stat")


def _children_map():
    """{parent pid: [child pids]} of every process now running."""
    out = {}
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat", "rb") as fh:
                stat = fh.read()
        except OSError:
            continue
        # the command name (in parentheses) may contain spaces: the parent id follows its last ')'
        ppid = int(stat[stat.rindex(b")") + 2 :].split()[1])
        out.setdefault(ppid, []).append(int(name))
    return out


def tree(pid):
    """``pid`` and every process descended from it."""
    kids = _children_map()
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(kids.get(p, ()))
    return out


def rss(pid):
    """Resident set size of ``pid`` in bytes (0 if it has gone)."""
    try:
        with open(f"/proc/{pid}/statm", "rb") as fh:
            return int(fh.read().split()[1]) * PAGE
    except (OSError, IndexError, ValueError):
        return 0


def pss(pid):
    """Proportional set size of ``pid`` in bytes (0 if it has gone or is unreadable)."""
    try:
        with open(f"/proc/{pid}/smaps_rollup", "rb") as fh:
            m = re.search(rb"^Pss:\s+(\d+) kB", fh.read(), re.M)
        return int(m.group(1)) * 1024 if m else 0
    except OSError:
        return 0


def mem_available():
    """The kernel's estimate of memory available to new work (bytes; None if unknown)."""
    try:
        with open("/proc/meminfo", "rb") as fh:
            m = re.search(rb"^MemAvailable:\s+(\d+) kB", fh.read(), re.M)
        return int(m.group(1)) * 1024 if m else None
    except OSError:
        return None


class _Watcher(threading.Thread):
    def __init__(self, pid, interval, pss_every, guard):
        super().__init__(daemon=True)
        self.pid, self.interval, self.pss_every, self.guard = pid, interval, pss_every, guard
        self.killed = False
        self.stop = threading.Event()
        self.stage = "start"
        self.peak = {"rss": 0, "pss": 0, "procs": 1}
        self.stages = {}  # stage -> {"rss": peak sum, "pss": peak sum}
        self.samples = 0

    def run(self):
        n = 0
        while not self.stop.is_set():
            pids = tree(self.pid)
            total = sum(rss(p) for p in pids)
            stage = self.stages.setdefault(self.stage, {"rss": 0, "pss": 0})
            stage["rss"] = max(stage["rss"], total)
            if total > self.peak["rss"]:
                self.peak["rss"], self.peak["procs"] = total, len(pids)
            if n % self.pss_every == 0:
                p = sum(pss(p) for p in pids)
                stage["pss"] = max(stage["pss"], p)
                self.peak["pss"] = max(self.peak["pss"], p)
            n += 1
            self.samples = n
            if self.guard and n % 5 == 0 and (mem_available() or self.guard) < self.guard:
                # the machine is about to run out: stop the measured tree rather than its neighbours
                for p in pids:
                    try:
                        os.kill(p, 9)
                    except OSError:
                        pass
                self.killed = True
            self.stop.wait(self.interval)


def run_measured(cmd, *, env=None, interval=0.02, pss_every=5, stage_prefix="facecap: [", guard=1 << 30):
    """Run ``cmd`` (argv list) and measure its process tree's memory.

    Returns
    -------
    dict with keys: returncode, seconds, tree_rss (peak of the summed RSS, bytes), tree_pss (peak
    of the summed PSS, bytes), main_rss (the main process's exact peak RSS, bytes), procs (processes
    at the RSS peak), stages ({stage line: {"rss", "pss"} peaks}, in order), stderr (its last lines),
    samples, killed (True if the tree was stopped because the machine had less than ``guard`` bytes
    available).
    """
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    watcher = _Watcher(proc.pid, interval, pss_every, guard)
    watcher.start()
    tail = []
    for line in proc.stderr:
        line = line.rstrip("\n")
        tail = (tail + [line])[-20:]
        if line.startswith(stage_prefix):
            watcher.stage = line[len(stage_prefix) - 1 :][:32]
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    watcher.stop.set()
    watcher.join()
    return dict(
        returncode=proc.returncode, seconds=time.perf_counter() - t0, tree_rss=watcher.peak["rss"],
        tree_pss=watcher.peak["pss"], main_rss=usage.ru_maxrss * 1024, procs=watcher.peak["procs"],
        stages=watcher.stages, stderr=tail, samples=watcher.samples, killed=watcher.killed,
    )
