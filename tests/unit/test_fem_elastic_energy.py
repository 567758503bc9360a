"""FEM's elastic_energy cell field (what a `total` probe of elastic_energy sums for FEM entities, and what the
coupling cases' energy checks add up): per element V psi(F) of the element's law. A block stretched uniformly
by 10% along x (initial_stretch) with the linear law stores mu eps:eps + lam/2 tr(eps)^2 per unit rest volume,
eps = diag(0.1, 0, 0); at rest it stores nothing."""

from __future__ import annotations

import numpy as np
import pytest

SCENE = """\
version: 1
sim: {{dim: 3, dt: 1.0e-3, steps: 1}}
domain: {{lower: [0, 0, 0], upper: [1, 1, 1]}}
solvers:
  fem: {{integrator: explicit, resolution: 20}}
entities:
  - name: block
    material: {{type: FEM.Elastic, E: 1.0e5, nu: 0.3, rho: 1000, model: linear{stretch}}}
    morph: {{type: Box, lower: [0.4, 0.4, 0.4], upper: [0.5, 0.6, 0.5]}}
"""


@pytest.mark.parametrize("stretch", [None, 1.1])
def test_fem_elastic_energy_is_the_laws_stored_energy(ti_f32, tmp_path, stretch):
    from simcli.scene.loader import load_scene
    from simcli.solvers.fem.solver import FEMSolver

    extra = "" if stretch is None else f", initial_stretch: [{stretch}, 1.0, 1.0]"
    p = tmp_path / "s.yaml"
    p.write_text(SCENE.format(stretch=extra))
    scene = load_scene(p).scene
    s = FEMSolver(scene, [], scene_dir=tmp_path)
    s.build()
    assert "elastic_energy" in s.output_fields() and "elastic_energy" in s.cell_fields
    e = s.entity_arrays("block", ["elastic_energy"])["elastic_energy"]
    assert e.shape == (s.m,)
    mat = scene.entities[0].material
    vol = 0.1 * 0.2 * 0.1
    eps = 0.0 if stretch is None else stretch - 1.0
    expected = (mat.mu * eps**2 + 0.5 * mat.lam * eps**2) * vol
    if stretch is None:
        assert np.abs(e).max() < 1e-6 * mat.mu * vol
    else:
        assert e.min() > 0.0
        assert e.sum() == pytest.approx(expected, rel=1e-4)


def test_fem_vertices_as_coupled_particles_leave_held_ones_out(ti_f32, tmp_path):
    """The FEM side of MPM <-> FEM and of the particle pairs (simcli/coupling/mpm_fem.py): lumped vertex
    masses at their positions, 0 for a vertex held by a fixed region (it is not coupled)."""
    import taichi as ti

    from simcli.coupling.mpm_fem import fem_particle_set
    from simcli.scene.loader import load_scene
    from simcli.solvers.fem.solver import FEMSolver

    p = tmp_path / "s.yaml"
    text = (
        SCENE.format(stretch="")
        + "    fixed: {type: Box, lower: [0.39, 0.39, 0.39], upper: [0.51, 0.61, 0.41]}\n"
    )
    p.write_text(text)
    s = FEMSolver(load_scene(p).scene, [], scene_dir=tmp_path)
    s.build()
    ps = fem_particle_set(s)
    out_m, out_x = ti.field(ti.f32, shape=s.n), ti.Vector.field(3, ti.f32, shape=s.n)

    @ti.kernel
    def read():
        for i in range(s.n):
            out_m[i] = ps.mass(i)
            out_x[i] = ps.pos(i)

    read()
    held = s.free.min(axis=1) == 0
    assert held.any() and not held.all()  # the bottom layer
    m = out_m.to_numpy()
    assert np.all(m[held] == 0.0)
    assert np.allclose(m[~held], s.mass[~held], rtol=1e-6)
    assert np.allclose(out_x.to_numpy(), s.xstart, atol=1e-6)
    assert ps.rho == 1000.0 and ps.move_x is s.x and ps.vel is s.v
