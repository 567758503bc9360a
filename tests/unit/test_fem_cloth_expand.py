"""FEM.Cloth's line-search expansion (ClothSolver._expand): a full Newton step whose energy drop shows that
the model Hessian overestimates the curvature along the step is doubled while the energy falls, within the
CCD's bound, and never to a higher energy. The energy along the step is a known 1D function here (the
method reads only _potential, _step_limit and the class constants), so each answer is exact."""

import numpy as np
import pytest

from simcli.solvers.fem.cloth.solver import ClothSolver


class _Line:
    """Phi(x) = -x0 + c / 2 x0^2 along the first coordinate (the model's curvature is 1: the Newton step
    from 0 is p = 1, g.p = -1); the CCD lets a step go as far as x0 = wall."""

    EXPAND_RATIO = ClothSolver.EXPAND_RATIO
    EXPAND_MAX = ClothSolver.EXPAND_MAX
    _expand = ClothSolver._expand

    def __init__(self, c: float, wall: float = np.inf) -> None:
        self.c, self.wall = c, wall
        self.stats = {"expansions": 0}
        self.evals = 0

    def phi(self, t: float) -> float:
        return -t + 0.5 * self.c * t * t

    def _potential(self, x, order, tau=None):
        self.evals += 1
        return (self.phi(float(x[0, 0])),)

    def _step_limit(self, x, p, tau=None, tau_to=None):
        return min(1.0, (self.wall - float(x[0, 0])) / float(p[0, 0]))

    def run(self):
        x = np.zeros((2, 3))
        p = np.zeros((2, 3))
        p[0, 0] = 1.0
        return self._expand(x, p, -1.0, self.phi(0.0), self.phi(1.0))


def test_an_exact_model_is_not_expanded():
    s = _Line(1.0)  # the Hessian is the energy's: the full step is the minimum
    a, xt, et = s.run()
    assert a == 1.0 and et == s.phi(1.0) and xt[0, 0] == 1.0
    assert s.evals == 0 and s.stats["expansions"] == 0


def test_a_soft_mode_is_expanded_towards_its_minimum():
    s = _Line(0.05)  # the model's curvature 20x the energy's: the minimum at alpha = 20
    a, xt, et = s.run()
    assert 10.0 <= a <= 40.0  # doubling brackets the minimum within a factor 2
    assert xt[0, 0] == pytest.approx(a) and et == pytest.approx(s.phi(a))
    assert et < s.phi(1.0) and et < s.phi(2.0 * a) and et < s.phi(0.5 * a)
    assert s.stats["expansions"] == 1


def test_the_expansion_stays_within_the_ccd_bound():
    s = _Line(0.05, wall=5.0)
    a, xt, et = s.run()
    assert a == pytest.approx(5.0)  # as far as the collision-free bound, not to the minimum at 20
    assert xt[0, 0] <= 5.0


def test_negative_curvature_stops_at_the_cap():
    s = _Line(-0.1)  # concave along p (a buckling mode): the energy falls without end
    a, _, et = s.run()
    assert a == pytest.approx(ClothSolver.EXPAND_MAX)
    assert et == pytest.approx(s.phi(ClothSolver.EXPAND_MAX))


def test_a_mild_mismatch_is_left_alone():
    s = _Line(0.6)  # ratio 1.4 < EXPAND_RATIO: the step is close enough to the minimum (1.67)
    a, _, _ = s.run()
    assert a == 1.0 and s.evals == 0
