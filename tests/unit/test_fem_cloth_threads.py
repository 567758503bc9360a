"""FEM.Cloth's host library ipctk keeps to the run's thread count (sim.threads, clamped; docs/LIMITS.md)."""

from __future__ import annotations

import subprocess
import sys
import textwrap


def test_ipctk_gets_the_threads_taichi_was_given(tmp_path):
    scene = tmp_path / "s.yaml"
    scene.write_text(
        textwrap.dedent(
            """\
            version: 1
            sim: {dim: 3, dt: 1.0e-2, substeps: 1, duration: 0.01}
            domain: {lower: [-1, -1, 0], upper: [1, 1, 1]}
            entities:
              - name: cloth
                material: {type: FEM.Cloth, E: 1.0e6, nu: 0.3, rho: 400, thickness: 5.0e-4}
                morph: {type: Rectangle, center: [0, 0, 0.5], size: [0.2, 0.2], resolution: 4}
            """
        )
    )
    code = textwrap.dedent(
        f"""\
        import ipctk, taichi as ti
        ipctk.set_num_threads(2)  # what it had before the solver (its default: every core)
        ti.init(arch=ti.cpu, cpu_max_num_threads=1)
        from simcli.scene.loader import load_scene
        from simcli.solvers.fem.cloth.solver import ClothSolver
        s = ClothSolver(load_scene({str(scene)!r}).scene, [], scene_dir=None)
        s.build()
        print("THREADS", ipctk.get_num_threads())
        """
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "THREADS 1" in r.stdout
