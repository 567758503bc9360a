"""The substep policy alone (simcli/substeps.py): numbers in, numbers out, no solver, no Taichi."""

from __future__ import annotations

import math

import pytest

from simcli.substeps import AUTO_MAX_SUBSTEPS, SubstepPolicy


def test_fixed_substeps_are_equal_and_end_on_the_step():
    p = SubstepPolicy(dt=1e-2, substeps=4, auto_check="frame", every=10)
    assert p.fixed() == 4 and not p.auto and p.step_substeps(0, 4, lambda fb: 1e-9) == 4
    done, k = 0.0, 0
    while True:
        sub, left = p.next_substep(k, done, 4, 1e-2, lambda fb: 1e-9)
        assert sub == 1e-2 / 4 and left == 4 - k
        k, done = k + 1, done + sub
        if left == 1:
            break
    assert k == 4 and done == pytest.approx(1e-2)


def test_auto_per_frame_chooses_at_a_frame_start_and_keeps_it():
    p = SubstepPolicy(dt=1e-2, substeps="auto", auto_check="frame", every=5)
    asked = []

    def stable(fb):
        asked.append(fb)
        return 3e-3

    assert p.step_substeps(0, None, stable) == 4  # ceil(1e-2 / 3e-3)
    assert p.step_substeps(3, 4, stable) == 4 and len(asked) == 1  # inside a frame: not asked again
    assert p.step_substeps(5, 4, stable) == 4 and asked[-1] == 1e-2 / 4  # the current substep as fallback
    assert p.step_substeps(10, 4, lambda fb: 0.0) == AUTO_MAX_SUBSTEPS  # a zero limit: capped, not infinite


def test_auto_per_substep_follows_the_limit_and_ends_without_a_sliver():
    p = SubstepPolicy(dt=1.0, substeps="auto", auto_check="substep", every=1)
    limits = iter([0.3, 0.3, 0.5, 0.5, 0.5])
    done, k, last, subs = 0.0, 0, 1.0, []
    while True:
        sub, left = p.next_substep(k, done, None, last, lambda fb: next(limits))
        subs.append(sub)
        k, done, last = k + 1, done + sub, sub
        if left == 1:
            break
    # 1.0 / ceil(1.0 / 0.3) = 0.25; the remaining 0.75 under 0.3: 0.25 again; then the limit grows to 0.5
    # and the remaining 0.5 is one substep: the step ends on its boundary
    assert subs == pytest.approx([0.25, 0.25, 0.5]) and done == pytest.approx(1.0)


def test_horizon_is_a_frame_unless_chosen_every_substep():
    assert SubstepPolicy(2e-3, "auto", "frame", 10).horizon(1e-4) == pytest.approx(2e-2)
    assert SubstepPolicy(2e-3, 5, "substep", 10).horizon(1e-4) == pytest.approx(
        2e-2
    )  # fixed: never re-chosen
    p = SubstepPolicy(2e-3, "auto", "substep", 10)
    assert p.horizon(None) == pytest.approx(2e-2) and p.horizon(1e-4) == 1e-4


@pytest.mark.parametrize("dt,stable,n", [(1.0, 2.0, 1), (1.0, 0.5, 2), (1.0, 0.3, 4), (1.0, 1.0 / 3, 3)])
def test_a_familys_own_split(dt, stable, n):
    assert SubstepPolicy.split(dt, stable) == n
    assert dt / n <= stable * (1 + 1e-9) and (n == 1 or dt / (n - 1) > stable)
    assert math.isfinite(dt / n)
