"""Progress: a live bar when stderr is a terminal, otherwise a plain log line every few
seconds (frame, sim time, steps/s, ETA). Never writes to stdout."""

from __future__ import annotations

import sys
import time


def _fmt_eta(seconds: float) -> str:
    if seconds != seconds or seconds == float("inf"):
        return "?"
    seconds = int(seconds)
    h, rem = divmod(seconds, 3600)
    m, s = divmod(rem, 60)
    return f"{h:d}:{m:02d}:{s:02d}" if h else f"{m:d}:{s:02d}"


class Progress:
    def __init__(
        self,
        total_steps: int,
        start_step: int,
        dt: float,
        quiet: bool = False,
        stream=None,
        interval_s: float | None = None,
    ):
        self.total = total_steps
        self.start = start_step
        self.dt = dt
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.interval = interval_s if interval_s is not None else (0.2 if self.tty else 5.0)
        self.t0 = time.perf_counter()
        self.last = self.t0
        self._drawn = False

    def update(self, step: int) -> None:
        if self.quiet:
            return
        now = time.perf_counter()
        if now - self.last < self.interval and step < self.total:
            return
        self.last = now
        done = step - self.start
        rate = done / max(now - self.t0, 1e-9)
        eta = (self.total - step) / rate if rate > 0 else float("inf")
        frac = step / max(self.total, 1)
        if self.tty:
            width = 30
            fill = int(round(frac * width))
            bar = "#" * fill + "-" * (width - fill)
            self.stream.write(
                f"\r[{bar}] {100 * frac:5.1f}% step {step}/{self.total} t={step * self.dt:.4g}s "
                f"{rate:.1f} steps/s ETA {_fmt_eta(eta)}  "
            )
            self._drawn = True
        else:
            self.stream.write(
                f"simcli: step {step}/{self.total} ({100 * frac:.1f}%) t={step * self.dt:.4g}s "
                f"{rate:.1f} steps/s ETA {_fmt_eta(eta)}\n"
            )
        self.stream.flush()

    def close(self) -> None:
        if self._drawn and self.tty and not self.quiet:
            self.stream.write("\n")
            self.stream.flush()
