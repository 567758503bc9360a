"""Coulomb friction at MPM grid nodes (simcli.colliders.contact_velocity), node by node: the
tangential velocity change is at most mu times the node's own normal velocity change, and a
frictional slip face is unilateral (issue 19: a bilateral frictional wall is not Coulomb)."""

import numpy as np
import pytest


@pytest.fixture(scope="module")
def contact(ti_f32):
    import taichi as ti

    from simcli.colliders import contact_velocity

    out = ti.Vector.field(2, ti.f32, shape=())

    def make(kind):
        @ti.kernel
        def k(vx: ti.f32, vy: ti.f32, mu: ti.f32):
            out[None] = contact_velocity(
                ti.Vector([vx, vy]), ti.Vector([0.0, 1.0]), ti.Vector([0.0, 0.0]), kind, mu
            )

        return k

    kernels = {kind: make(kind) for kind in ("slip", "separate")}

    def run(kind, v, mu):
        kernels[kind](v[0], v[1], mu)
        return out.to_numpy()

    return run


@pytest.mark.parametrize("kind", ["slip", "separate"])
def test_compressed_node_loses_mu_times_its_normal_velocity_change(contact, kind):
    v = contact(kind, (1.0, -0.2), 0.5)
    np.testing.assert_allclose(v, [0.9, 0.0], atol=1e-7)  # |dv_t| = mu |dv_n| = 0.1
    np.testing.assert_allclose(contact(kind, (0.05, -0.2), 0.5), [0.0, 0.0], atol=1e-7)  # sticks


@pytest.mark.parametrize("kind", ["slip", "separate"])
def test_frictional_face_releases_a_node_leaving_it(contact, kind):
    # a tensile normal impulse carries no friction: holding the node would break Coulomb's law
    np.testing.assert_allclose(contact(kind, (1.0, 0.2), 0.5), [1.0, 0.2], atol=1e-7)


def test_frictionless_slip_face_still_holds_both_ways(contact):
    np.testing.assert_allclose(contact("slip", (1.0, 0.2), 0.0), [1.0, 0.0], atol=1e-7)
    np.testing.assert_allclose(contact("slip", (1.0, -0.2), 0.0), [1.0, 0.0], atol=1e-7)
    np.testing.assert_allclose(contact("separate", (1.0, 0.2), 0.0), [1.0, 0.2], atol=1e-7)
