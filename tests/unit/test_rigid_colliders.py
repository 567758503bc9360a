"""Rigid bodies against the scene's colliders (issue 20: "colliders pushing rigid bodies"): a collider is a
body of infinite mass moving as prescribed. In one 3D run: a Mesh cube turned to lie flat on a slab (a Mesh
collider tilted 25 degrees) slides down it as Coulomb says, a Box body rests on a Box collider (a shelf),
and a Sphere body on the floor is pushed by a Box collider moving at 0.3 m/s. The material is a few PBD
particles (the contact is the bodies' own, on the host; MPM's kernels with these four Mesh and moving
colliders take minutes to compile)."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
CUBE = ROOT / "configs" / "meshes" / "cube.obj"
A = math.radians(25.0)
N = np.array([-math.sin(A), 0.0, math.cos(A)])  # the slope's normal: it rises towards +x
U = np.array([math.cos(A), 0.0, math.sin(A)])  # up the slope
S = np.array([0.35, 0.1, 0.15])  # the slab's centre (0.3 m along the slope, 0.2 m wide, 0.04 m thick)
P0 = S + 0.02 * N  # a point of its top face
C0 = P0 + 0.0201 * N + 0.08 * U  # the 0.04 m cube's centre, its face 0.1 mm above the slope, up it
MU = 0.3  # body 0.3 and collider 0.3: their geometric mean

SCENE = f"""\
version: 1
sim: {{dim: 3, dt: 2.0e-3, substeps: 2, duration: 0.3}}
domain: {{lower: [0.0, 0.0, 0.0], upper: [0.6, 0.2, 0.4]}}
solvers:
  pbd: {{particle_size: 0.01}}
colliders:
  - {{type: Mesh, file: {CUBE}, scale: [0.3, 0.2, 0.04], rotate: [0, -25, 0], translate: {S.tolist()},
     friction: {MU}}}
  - {{type: Box, lower: [0.45, 0.0, 0.25], upper: [0.6, 0.2, 0.28]}}
  - {{name: pusher, type: Box, lower: [0.0, 0.05, 0.0], upper: [0.04, 0.15, 0.06],
     motion: {{linear_velocity: [0.3, 0.0, 0.0]}}}}
entities:
  - name: pad
    material: {{type: PBD.Particle, rho: 1000}}
    morph: {{type: Box, lower: [0.5, 0.0, 0.0], upper: [0.6, 0.05, 0.03]}}
rigid_bodies:
  - name: slider
    morph: {{type: Mesh, file: {CUBE}, scale: 0.04, rotate: [0, -25, 0],
             translate: {C0.tolist()}}}
    rho: 500
    friction: {MU}
  - {{name: shelved, morph: {{type: Box, center: [0.52, 0.1, 0.305], size: [0.05, 0.05, 0.05]}}, rho: 500}}
  - {{name: pushed, morph: {{type: Sphere, center: [0.1, 0.1, 0.031], radius: 0.03}}, rho: 500}}
output: {{every: 5, formats: [hdf5]}}
"""


def test_bodies_slide_rest_and_are_pushed_on_colliders(tmp_path):
    scene = tmp_path / "scene.yaml"
    scene.write_text(SCENE)
    out = tmp_path / "out"
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "run", str(scene), "-o", str(out)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=600,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    with h5py.File(out / "sim.h5", "r") as f:
        t = np.asarray(f["time"][...])
        g = f["rigid_bodies"]
        xs, qs = np.asarray(g["slider"]["position"]), np.asarray(g["slider"]["orientation"])
        shelf = np.asarray(g["shelved"]["position"])
        ball = np.asarray(g["pushed"]["position"])
        vball = np.asarray(g["pushed"]["velocity"])
    # Coulomb on the slope: s = g (sin a - mu cos a) t^2 / 2 down it, no tipping, on its face
    down = -U
    s = (xs[-1] - xs[0]) @ down
    s_ref = 0.5 * 9.81 * (math.sin(A) - MU * math.cos(A)) * t[-1] ** 2
    assert s == pytest.approx(s_ref, rel=0.03)
    assert np.abs((xs - P0) @ N - 0.02).max() < 1e-3
    assert np.abs(np.abs(qs[:, 0]) - 1.0).max() < 1e-6  # the orientation stays the initial one
    # the shelf holds its body where it was put
    assert np.abs(shelf - shelf[0]).max() < 1e-3
    # the pusher (right face at 0.04 + 0.3 t) reaches the ball (left side at 0.07) at t = 0.1 s and carries it
    late = t > 0.2
    assert np.all(np.abs(ball[late, 0] - 0.03 - (0.04 + 0.3 * t[late])) < 2e-3)
    assert np.all(np.abs(vball[late, 0] - 0.3) < 1e-2)
    assert np.abs(ball[:, 2] - 0.03).max() < 2e-3  # on the floor throughout
