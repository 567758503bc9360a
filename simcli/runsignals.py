"""Signal handling of `simcli run`, kept free of heavy imports so that `simcli run` installs it
before anything else (loading the scene, importing numpy, h5py or Taichi): a SIGTERM during start-up
is then recorded and honoured at the next start-up phase instead of killing the process with no
run.json (the default action)."""

from __future__ import annotations

import signal


class RunSignals:
    """SIGTERM, SIGINT, SIGUSR1: recorded; the runner finishes the current step (or start-up phase),
    checkpoints if there is anything to keep, and exits 75."""

    NAMES = ("SIGTERM", "SIGINT", "SIGUSR1")

    def __init__(self):
        self.received: str | None = None
        self._old: dict = {}

    def _handler(self, signum, frame):
        if self.received is not None and signum == signal.SIGINT:
            # a second Ctrl-C: the user really wants out
            raise KeyboardInterrupt
        self.received = signal.Signals(signum).name

    def install(self) -> "RunSignals":
        # a write past the file-size limit (`ulimit -f`) must fail with EFBIG, which the writers report as an
        # output error (exit 74), not kill the process: Python ignores SIGXFSZ at start-up; make sure
        if hasattr(signal, "SIGXFSZ"):
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        for n in self.NAMES:
            s = getattr(signal, n, None)
            if s is not None:
                old = signal.signal(s, self._handler)
                if old is not self._handler and getattr(old, "__self__", None) is not self:
                    self._old.setdefault(s, old)
        return self

    def restore(self) -> None:
        for s, h in self._old.items():
            signal.signal(s, h)
