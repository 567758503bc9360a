"""CPU-time durations of the test suite: a pytest plugin, off unless named.

    python -m pytest -q -p tests.cpu_durations [tests/...]

On a machine shared with other Taichi jobs, wall-clock durations (``--durations``) mostly measure the
wait for a core (wall / CPU ratios of 6-9 were seen with five other engineers' runs on 2 cores). This
records, per test phase (setup, call, teardown), the CPU seconds of the test process and of the child
processes it waited for (``simcli run`` subprocesses), and prints the 30 largest at the end with the
totals. ``SIMCLI_CPU_DURATIONS=path.tsv`` also writes every row (nodeid, phase, wall, self, children).
CPU seconds are not wall seconds on an idle 2-core CI machine (Taichi runs parallel loops and compiles
on up to 2 threads), but their order does not depend on what else the machine is running.
"""

from __future__ import annotations

import os
import resource
import time

import pytest

_ROWS: list[tuple[str, str, float, float, float]] = []


def _cpu() -> tuple[float, float]:
    s = resource.getrusage(resource.RUSAGE_SELF)
    c = resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime, c.ru_utime + c.ru_stime


def _measure(item, phase):
    t0 = time.perf_counter()
    s0, c0 = _cpu()
    yield
    s1, c1 = _cpu()
    _ROWS.append((item.nodeid, phase, time.perf_counter() - t0, s1 - s0, c1 - c0))


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_setup(item):
    yield from _measure(item, "setup")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_call(item):
    yield from _measure(item, "call")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_teardown(item):
    yield from _measure(item, "teardown")


def pytest_terminal_summary(terminalreporter):
    if not _ROWS:
        return
    path = os.environ.get("SIMCLI_CPU_DURATIONS")
    if path:
        with open(path, "w") as f:
            f.write("nodeid\tphase\twall_s\tself_cpu_s\tchild_cpu_s\n")
            for r in _ROWS:
                f.write(f"{r[0]}\t{r[1]}\t{r[2]:.3f}\t{r[3]:.3f}\t{r[4]:.3f}\n")
    tr = terminalreporter
    tr.write_sep("=", "largest CPU times (self + waited-for children), tests/cpu_durations.py")
    for nodeid, phase, wall, own, child in sorted(_ROWS, key=lambda r: -(r[3] + r[4]))[:30]:
        tr.write_line(
            f"{own + child:8.2f}s cpu ({own:7.2f} self {child:7.2f} children) {wall:8.2f}s wall "
            f"{phase:8s} {nodeid}"
        )
    wall = sum(r[2] for r in _ROWS)
    own = sum(r[3] for r in _ROWS)
    child = sum(r[4] for r in _ROWS)
    tr.write_line(f"total: {own + child:.1f}s cpu ({own:.1f} self, {child:.1f} children), {wall:.1f}s wall")
