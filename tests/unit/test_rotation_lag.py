"""Regression: the warm-started rotation of the corotated law must follow slow rotations.

With a loose stopping tolerance (2e-5 rad in f32) the extraction skipped every update whose
increment was below it, so R lagged F by up to that angle: a stick-slip stress comparable to
a stiff body's strains, which damped a 3D cantilever critically and made it 30% too soft.
A particle turned by many tiny increments (as a bending beam is, substep by substep) must stay
free of stress."""

import numpy as np


def test_pure_rotation_in_tiny_increments_stays_stress_free(ti_f32):
    import taichi as ti

    from simcli.solvers.mpm.constitutive import CorotatedLaw

    law = CorotatedLaw(3, ti.f32)
    law.allocate(1)
    law.init_state()
    F = ti.Matrix.field(3, 3, ti.f32, shape=())
    tau_out = ti.Matrix.field(3, 3, ti.f32, shape=())

    @ti.kernel
    def stress(mu: ti.f32):
        for _ in range(1):  # the extraction's own loop must not be the kernel's outermost one
            Fp = F[None]
            tau_out[None] = law.kirchhoff(0, Fp, Fp.determinant(), mu, 0.0, True)

    mu = 1.0
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    worst = 0.0
    for k in range(1, 301):
        theta = 4.0e-6 * k  # per-substep increments of 4e-6 rad: below the old tolerance
        R = np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * K @ K
        F[None] = R.astype(np.float32)
        stress(mu)
        worst = max(worst, np.abs(tau_out[None].to_numpy()).max())
    # f32 round-off of F itself is ~1e-7; the lagging rotation gave up to 2 mu * 1.2e-3 here
    assert worst < 2.0e-6 * mu, worst
