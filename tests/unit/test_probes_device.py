"""The probes' device path (simcli/probes/device.py) gives the host path's values bit for bit: point probes
(pressure, velocity, density) and height gauges (highest and connected) of SPH and MPM entities, with several
entities and with emitters and sinks (output order by particle id), after a few substeps of motion."""

from __future__ import annotations

import numpy as np
import pytest

SPH = """\
version: 1
sim: {{dim: {dim}, dt: 2.0e-3, steps: 1}}
domain: {{lower: {lo}, upper: {hi}}}
solvers:
  sph: {{particle_size: 0.02, pressure_solver: DFSPH}}
entities:
  - name: a
    material: {{type: SPH.Liquid, rho: 1000}}
    morph: {{type: Box, lower: {alo}, upper: {ahi}}}
  - name: b
    material: {{type: SPH.Liquid, rho: 800}}
    morph: {{type: Box, lower: {blo}, upper: {bhi}}}
{extra}probes:
{probes}
"""

MPM = """\
version: 1
sim: {{dim: {dim}, dt: 2.0e-3, steps: 1}}
domain: {{lower: {lo}, upper: {hi}}}
solvers:
  mpm: {{grid_density: 32}}
entities:
  - name: a
    material: {{type: MPM.Liquid, E: 2.0e5, nu: 0.3, rho: 1000}}
    morph: {{type: Box, lower: {alo}, upper: {ahi}}}
  - name: b
    material: {{type: MPM.Elastic, E: 1.0e5, nu: 0.3, rho: 800}}
    morph: {{type: Box, lower: {blo}, upper: {bhi}}}
{extra}probes:
{probes}
"""


def _geometry(dim):
    z = lambda v: v if dim == 3 else v[:1] + v[2:]  # noqa: E731 - [x, y, z] -> [x, z] in 2D
    return dict(
        lo=[0.0] * dim,
        hi=z([0.6, 0.3, 0.6]),
        alo=z([0.0, 0.0, 0.0]),
        ahi=z([0.3, 0.3, 0.3]),
        blo=z([0.32, 0.0, 0.0]),
        bhi=z([0.5, 0.3, 0.2]),
    )


def _probes(dim, family):
    z = lambda v: v if dim == 3 else v[:1] + v[2:]  # noqa: E731
    qs = ["pressure", "velocity", "density"]
    lines = []
    for k, at in enumerate(
        [z([0.15, 0.15, 0.1]), z([0.31, 0.1, 0.05]), z([0.45, 0.2, 0.15]), z([0.55, 0.15, 0.55])]
    ):
        for q in qs:
            lines.append(f"  - {{name: {q}{k}, type: point, quantity: {q}, position: {at}, every: 1}}")
    for k, at in enumerate([z([0.1, 0.2])[: dim - 1], z([0.4, 0.1])[: dim - 1], z([0.58, 0.2])[: dim - 1]]):
        lines.append(f"  - {{name: h{k}, type: height, position: {at}, every: 1}}")
        lines.append(f"  - {{name: c{k}, type: height, position: {at}, surface: connected, entity: b}}")
    lines.append(
        "  - {name: pa, type: point, quantity: pressure, position: " + str(z([0.1] * 3)) + ", entity: a}"
    )
    return "\n".join(lines)


SINK = "sinks:\n  - {{name: drain, type: Box, lower: {lo}, upper: {hi}}}\n"


def _solvers(tmp_path, family, dim, sink):
    from simcli.geometry.sampling import sample_scene
    from simcli.scene.loader import load_scene
    from simcli.solvers import make_solvers

    g = _geometry(dim)
    extra = ""
    if sink:  # a sink over the lower-left corner: particles leave, the rest keep their ids (active mode)
        extra = SINK.format(lo=[-0.01] * dim, hi=[0.08] * dim)
    text = (SPH if family == "sph" else MPM).format(dim=dim, extra=extra, probes=_probes(dim, family), **g)
    p = tmp_path / "s.yaml"
    p.write_text(text)
    scene = load_scene(p).scene
    bodies = sample_scene(scene, tmp_path, 0)
    solvers = make_solvers(scene, bodies, scene_dir=tmp_path)
    for s in solvers:
        s.build()
    return scene, solvers


@pytest.mark.parametrize("family,dim,sink", [("sph", 2, False), ("mpm", 3, False), ("mpm", 2, True)])
def test_device_probes_equal_the_host_path(ti_f32, tmp_path, family, dim, sink, monkeypatch):
    from simcli.probes.device import FamilySampler
    from simcli.probes.recorder import ProbeRecorder
    from simcli.solvers.sources import SourceRun

    monkeypatch.setattr(FamilySampler, "CAP0", 8)  # the first sample overflows the table: it grows
    scene, solvers = _solvers(tmp_path, family, dim, sink)
    dev = ProbeRecorder(scene, solvers, tmp_path, device=True)
    host = ProbeRecorder(scene, solvers, tmp_path, device=False)
    run = SourceRun(scene, solvers) if sink else None
    due = list(range(len(dev.probes)))
    dev_probes = [i for i, (p, e) in enumerate(zip(dev.probes, dev.entities)) if dev._device_probe(p, e)]
    assert len(dev_probes) == len(due)  # every probe here takes the device path
    for step in range(4):
        for _ in range(5):
            if run is not None:
                run.before_substep(step * 0.01)
            solvers[0].substep(2.0e-3)
        solvers[0].sync()
        if run is not None:
            run.after_step()
        a, b = dev.values(due), host.values(due)
        dry = set()
        for i in due:
            np.testing.assert_array_equal(a[i], b[i], err_msg=dev.probes[i].name)  # NaN == NaN here
            if not np.all(np.isfinite(a[i])):
                dry.add(dev.probes[i].name)
        # NaN: the point at x = 0.55 (3 probes), gauge h2 (x = 0.58), c0 and c2 (entity b is not there) and
        # in MPM h1 (over b, elastic: '*' gauges read liquids); the others read particles
        assert dry <= {"pressure3", "velocity3", "density3", "h1", "h2", "c0", "c2"}, dry
        assert "pressure0" not in dry and "c1" not in dry
    assert dev._samplers[0][0].cap > 8
    if sink:
        assert solvers[0].n_live() < solvers[0].n  # particles left through the sink
