"""Progress: a live bar when stderr is a terminal, otherwise a plain log line every few
seconds (frame, sim time, steps/s, ETA). Never writes to stdout.

What the numbers mean (the first seconds of a run are Taichi compiling its kernels, which must not
be read as the run's speed):

* ``steps/s`` is run.json's ``throughput.steps_per_s``: steps done in this process over the time
  spent stepping (the runner's ``stepping_s``: kernel compilation, which the first substep carries,
  output and checkpoints excluded). Until the runner reports stepping time it is measured on the
  wall clock from the first steady point (below).
* ``ETA`` is wall-clock time: the remaining steps at the wall-clock pace since the first steady
  point, the end of the first output frame (``warmup_steps`` steps in: by then every kernel of a
  step and of a frame has been compiled), so it includes output and checkpoints but no compilation.
  Before that point it is estimated from the stepping rate; with neither it is ``?``.
"""

from __future__ import annotations

import math
import sys
import time


def plural(n: int, noun: str, nouns: str | None = None) -> str:
    """``1 entity``, ``2 entities``, ``0 frames``."""
    if n == 1:
        return f"{n} {noun}"
    if nouns is None:
        nouns = noun[:-1] + "ies" if noun.endswith("y") and noun[-2:-1] not in "aeiou" else noun + "s"
    return f"{n} {nouns}"


def _fmt_eta(seconds: float | None) -> str:
    if seconds is None or not math.isfinite(seconds):
        return "?"
    seconds = int(round(seconds))
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
        warmup_steps: int = 1,
        clock=time.perf_counter,
    ):
        self.total = total_steps
        self.start = start_step
        self.dt = dt
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.interval = interval_s if interval_s is not None else (0.2 if self.tty else 5.0)
        self.warmup = max(1, min(int(warmup_steps), max(total_steps - start_step, 1)))
        self.clock = clock
        self.t0 = clock()
        self.last = self.t0
        self.base: tuple[float, int] | None = None  # (wall time, step) of the first steady point
        self._drawn = False

    # -- the arithmetic ---------------------------------------------------------------------
    def observe(self, step: int, now: float) -> None:
        if self.base is None and step - self.start >= self.warmup:
            self.base = (now, step)

    def rate(self, step: int, now: float, stepping_s: float | None = None) -> float | None:
        """Steps per second: run.json's definition when the stepping time is known."""
        done = step - self.start
        if stepping_s is not None and stepping_s > 0 and done > 0:
            return done / stepping_s
        if self.base is not None and step > self.base[1] and now > self.base[0]:
            return (step - self.base[1]) / (now - self.base[0])
        return None

    def eta(self, step: int, now: float, stepping_s: float | None = None) -> float | None:
        """Wall-clock seconds left."""
        left = max(self.total - step, 0)
        if left == 0:
            return 0.0
        if self.base is not None and step > self.base[1] and now > self.base[0]:
            return left * (now - self.base[0]) / (step - self.base[1])
        r = self.rate(step, now, stepping_s)
        return left / r if r else None

    # -- output -----------------------------------------------------------------------------
    def update(self, step: int, stepping_s: float | None = None) -> None:
        """Called after each step; ``stepping_s``: stepping seconds of this process so far (the
        runner's, as in run.json)."""
        now = self.clock()
        self.observe(step, now)
        if self.quiet:
            return
        if now - self.last < self.interval and step < self.total:
            return
        self.last = now
        self.stream.write(self.line(step, now, stepping_s))
        if self.tty:
            self._drawn = True
        self.stream.flush()

    def line(self, step: int, now: float, stepping_s: float | None = None) -> str:
        rate = self.rate(step, now, stepping_s)
        rate_s = f"{rate:.1f} steps/s" if rate is not None else "? steps/s"
        eta_s = _fmt_eta(self.eta(step, now, stepping_s))
        frac = step / max(self.total, 1)
        if self.tty:
            width = 30
            fill = int(round(frac * width))
            bar = "#" * fill + "-" * (width - fill)
            return (
                f"\r[{bar}] {100 * frac:5.1f}% step {step}/{self.total} t={step * self.dt:.4g}s "
                f"{rate_s} ETA {eta_s}  "
            )
        return (
            f"simcli: step {step}/{self.total} ({100 * frac:.1f}%) t={step * self.dt:.4g}s "
            f"{rate_s} ETA {eta_s}\n"
        )

    def close(self) -> None:
        if self._drawn and self.tty and not self.quiet:
            self.stream.write("\n")
            self.stream.flush()
