"""A batch's progress: a tqdm bar with the ETA on a terminal, plain lines otherwise (a log file, CI,
a farm's job output).

tqdm is a dependency of the pip package (small, pure Python, no dependencies of its own, maintained
for a decade, and it draws correctly in narrow terminals, over SSH and in Windows consoles); inside a
Blender without it the plain lines are used.
"""

import time

try:
    from tqdm import tqdm
except ImportError:  # a Blender without the pip dependencies: plain lines
    tqdm = None


class Progress:
    """``finished(record)`` per take; ``close()`` at the end. ``stream``: where to draw (stderr)."""

    def __init__(self, total, stream, *, bar=None, quiet=False):
        self.total, self.stream, self.quiet = total, stream, quiet
        self.done = self.failed = 0
        self.t0 = time.monotonic()
        terminal = getattr(stream, "isatty", lambda: False)()
        use_bar = (terminal and tqdm is not None and not quiet) if bar is None else bar
        self.bar = tqdm(total=total, file=stream, unit="take", dynamic_ncols=True, smoothing=0.05,
                        desc="facecap batch") if use_bar and total else None

    def finished(self, record):
        self.done += 1
        failed = record["status"] in ("failed", "cancelled")
        self.failed += failed
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix_str(f"{self.failed} failed" if self.failed else "", refresh=True)
            if failed:
                self.bar.write(f"facecap: {record['status'].upper()} {record['take']}: {record['error']}",
                               file=self.stream)
            return
        if failed or not self.quiet:  # --quiet: only the takes that failed
            print(f"facecap: [{self.done}/{self.total}] {self.describe(record)}; {self.eta()}", file=self.stream,
                  flush=True)

    @staticmethod
    def describe(record):
        if record["status"] != "ok":
            return f"{record['status'].upper()} {record['take']}: {record['error']}"
        residual = "" if record.get("residual_mm") is None else f", {record['residual_mm']:.3f} mm"
        seconds = (record.get("seconds") or {}).get("total")
        timing = "" if seconds is None else f", {seconds:.1f} s"
        return f"ok {record['take']} ({record['frames']} frames{residual}{timing})"

    def eta(self):
        """Elapsed and the estimated time left (takes finish at the rate seen so far)."""
        elapsed = time.monotonic() - self.t0
        left = elapsed / self.done * (self.total - self.done) if self.done else float("nan")
        if self.done >= self.total:
            return f"elapsed {_clock(elapsed)}"
        return f"elapsed {_clock(elapsed)}, eta {_clock(left)}"

    def close(self):
        if self.bar is not None:
            self.bar.close()


def _clock(seconds):
    if seconds != seconds:  # NaN: nothing finished yet
        return "?"
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"
