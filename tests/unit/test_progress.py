"""Progress arithmetic with a fake clock: Taichi's compilation at the start must not enter the rate
or the ETA, and the rate is run.json's (steps over stepping time)."""

from __future__ import annotations

import io

import pytest

from simcli.progress import Progress, _fmt_eta, plural


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def simulate(
    p: Progress, clock: Clock, upto: int, start: int = 0, compile_s=30.0, step_s=0.02, frame_s=0.5, every=100
):
    """A run as the runner drives it: the first step carries `compile_s` of compilation (not in
    stepping time); each step `step_s` of stepping; every `every` steps a frame costing `frame_s`."""
    stepping = 0.0
    for step in range(start + 1, upto + 1):
        clock.t += step_s + (compile_s if step == start + 1 else 0.0)
        stepping += step_s
        if step % every == 0:
            clock.t += frame_s
        p.update(step, stepping)
    return stepping


def test_first_eta_excludes_compilation():
    clock = Clock()
    out = io.StringIO()
    p = Progress(1000, 0, 1e-3, stream=out, interval_s=0.0, warmup_steps=100, clock=clock)
    stepping = simulate(p, clock, 1)
    assert clock.t == pytest.approx(30.02)
    # rate as in run.json: steps / stepping seconds (the compiling first substep is not in them)
    assert p.rate(1, clock.t, stepping) == pytest.approx(50.0)
    # no steady wall-clock point yet: the ETA comes from the stepping rate, not from 30 s per step
    assert p.eta(1, clock.t, stepping) == pytest.approx(999 / 50.0)
    assert out.getvalue().splitlines()[0].endswith("50.0 steps/s ETA 0:20")


def test_eta_from_the_wall_clock_after_the_first_frame():
    clock = Clock()
    p = Progress(1000, 0, 1e-3, stream=io.StringIO(), interval_s=0.0, warmup_steps=100, clock=clock)
    stepping = simulate(p, clock, 300)
    # the steady point is the end of the first frame (step 100, its output included)
    assert p.base == (pytest.approx(30.0 + 100 * 0.02 + 0.5), 100)
    # from there: 200 steps of 0.02 s and 2 frames of 0.5 s = 5 s -> 700 steps left take 17.5 s
    assert p.eta(300, clock.t, stepping) == pytest.approx(17.5)
    # the rate stays run.json's: 300 steps / 6 s of stepping
    assert p.rate(300, clock.t, stepping) == pytest.approx(300 / stepping) == pytest.approx(50.0)
    assert p.eta(1000, clock.t, stepping) == 0.0


def test_resumed_run_counts_its_own_steps():
    clock = Clock()
    p = Progress(1000, 600, 1e-3, stream=io.StringIO(), interval_s=0.0, warmup_steps=100, clock=clock)
    stepping = simulate(p, clock, 800, start=600)
    assert p.rate(800, clock.t, stepping) == pytest.approx(50.0)  # 200 steps in 4 s of stepping
    assert p.base[1] == 700
    assert p.eta(800, clock.t, stepping) == pytest.approx(200 * (100 * 0.02 + 0.5) / 100)


def test_without_stepping_time_nothing_is_guessed_before_the_steady_point():
    clock = Clock()
    out = io.StringIO()
    p = Progress(1000, 0, 1e-3, stream=out, interval_s=0.0, warmup_steps=10, clock=clock)
    clock.t = 30.0
    p.update(1)
    assert out.getvalue().rstrip().endswith("? steps/s ETA ?")
    for step in range(2, 21):
        clock.t += 0.1
        p.update(step)
    assert p.base == (pytest.approx(30.9), 10)
    assert p.rate(20, clock.t) == pytest.approx(10.0)
    assert p.eta(20, clock.t) == pytest.approx(98.0)


def test_quiet_writes_nothing_and_tty_bar():
    clock = Clock()
    out = io.StringIO()
    p = Progress(10, 0, 0.1, quiet=True, stream=out, interval_s=0.0, clock=clock)
    simulate(p, clock, 10, every=5)
    p.close()
    assert out.getvalue() == ""

    class Tty(io.StringIO):
        def isatty(self):
            return True

    tty = Tty()
    p = Progress(10, 0, 0.1, stream=tty, interval_s=0.0, warmup_steps=5, clock=clock)
    simulate(p, clock, 10, every=5)
    p.close()
    assert tty.getvalue().startswith("\r[") and tty.getvalue().endswith("\n")
    assert "100.0% step 10/10" in tty.getvalue()


def test_eta_format_and_plural():
    assert _fmt_eta(None) == "?" and _fmt_eta(float("inf")) == "?"
    assert _fmt_eta(42.4) == "0:42" and _fmt_eta(8109) == "2:15:09"
    assert plural(1, "entity") == "1 entity" and plural(2, "entity") == "2 entities"
    assert plural(0, "frame") == "0 frames" and plural(1, "step") == "1 step" and plural(3, "day") == "3 days"
