"""Mesh colliders in SPH and SF (issue 19; no Taichi): a cube given as a mesh is, to those families, the
Box collider of the same shape: SF's solid cells are the same cells (but at the edges, which its grid
rounds), and SPH's boundary particles fill the
same shell (sampled from the mesh's signed-distance grid on a lattice, where a Box fits its own)."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[2]
CUBE = ROOT / "configs" / "meshes" / "cube.obj"


def _scene(text: str):
    from simcli.scene.models import Scene

    return Scene.model_validate(yaml.safe_load(textwrap.dedent(text)))


def test_sf_solid_cells_of_a_mesh_cube_are_the_box_s():
    from simcli.solvers.sf.grid import collider_mask, make_layout

    base = """\
    version: 1
    sim: {{dim: 3, dt: 0.02, steps: 1}}
    domain: {{lower: [-0.5, -0.5, 0.0], upper: [0.5, 0.5, 1.0]}}
    colliders:
      - {col}
    solvers:
      sf: {{resolution: 24}}
    entities:
      - name: smoke
        material: {{type: SF.Smoke}}
    """
    box = _scene(base.format(col="{type: Box, lower: [-0.21, -0.13, 0.31], upper: [0.19, 0.27, 0.71]}"))
    mesh = _scene(
        base.format(
            col=f"{{type: Mesh, file: {CUBE}, scale: 0.4, translate: [-0.01, 0.07, 0.51]}}",
        )
    )
    from simcli.colliders import collider_specs, sdf_np

    L = make_layout(box, box.solvers.sf)
    a, b = collider_mask(box, L), collider_mask(mesh, make_layout(mesh, mesh.solvers.sf))
    # the same cells, but where the grid rounds the cube's edges (about one of its cells: docs): there a
    # cell just inside the exact box may read outside
    (sb,), (sm,) = collider_specs(box, 3), collider_specs(mesh, 3)
    x = np.stack([c.ravel() for c in L.cell_centres()], axis=1)
    differ = (a != b).ravel()
    assert a.sum() > 0 and differ.sum() <= 0.02 * a.sum()
    assert np.all(np.abs(sdf_np(sb, x[differ])) < sm.mesh.h)


def test_sph_boundary_particles_of_a_mesh_cube_fill_the_box_s_shell():
    from simcli.colliders import collider_specs, sdf_np
    from simcli.solvers.sph.boundary import LAYERS, collider_particles

    base = """\
    version: 1
    sim: {{dim: 3, dt: 0.002, steps: 1}}
    domain: {{lower: [0.0, 0.0, 0.0], upper: [0.4, 0.4, 0.4]}}
    colliders:
      - {col}
    solvers:
      sph: {{particle_size: 0.02}}
    entities:
      - name: water
        material: {{type: SPH.Liquid}}
        morph: {{type: Box, lower: [0.0, 0.0, 0.0], upper: [0.4, 0.4, 0.05]}}
    """
    box = _scene(base.format(col="{type: Box, lower: [0.1, 0.1, 0.1], upper: [0.3, 0.3, 0.3]}"))
    mesh = _scene(base.format(col=f"{{type: Mesh, file: {CUBE}, scale: 0.2, translate: [0.2, 0.2, 0.2]}}"))
    h = 0.02
    lo, hi = [0.0] * 3, [0.4] * 3
    (sb,), (sm,) = collider_specs(box, 3), collider_specs(mesh, 3)
    pb, pm = collider_particles(sb, lo, hi, h, 3), collider_particles(sm, lo, hi, h, 3)
    # the same number of particles (same volume of shell), all inside the exact box, within the layers
    assert abs(pm.n - pb.n) <= 0.05 * pb.n
    d = sdf_np(sb, pm.x)
    assert np.all(d < 0) and np.all(d >= -LAYERS * h - 1e-9)
    assert np.sum(pm.volume) == np.sum(pb.volume) or abs(np.sum(pm.volume) / np.sum(pb.volume) - 1) < 0.05
