"""add_sources: the first stage of a step (Stam 1999: w1 = w0 + dt f; s1 = s0 + dt S).

In one kernel launch:

* jets add smoke and heat (rates times dt, weighted by how much of the cell the jet covers),
* smoke decays and heat relaxes to ambient exponentially (exact for the step, any dt),
* forces act on the face velocities: Boussinesq buoyancy (alpha s - beta (T - T_ambient)) g
  (Fedkiw et al. 2001), optional vorticity confinement epsilon dx (N x omega), and jets (an
  imposed velocity, an inlet, or an added acceleration, Genesis's impulse),
* fixed faces are reset and the ghost layers refreshed for the advection that follows.

A jet's centre, velocity and force at the current time are computed on the host from the scene
(``Jet.state``: fixed, orbiting, or along waypoints) and passed as a small kernel argument, so a
moving jet costs no field upload and no recompilation.
"""

import numpy as np

from simcli.backend import stdout_to_stderr
from simcli.solvers.sf.boundary import Boundary
from simcli.solvers.sf.grid import SOLID, Layout

with stdout_to_stderr():
    import taichi as ti


def jet_row_width(dim: int) -> int:
    return 3 * dim + 4  # centre, velocity, force (x on), radius, smoke rate, heat rate, velocity on


class Sources:
    def __init__(
        self, layout: Layout, f, bc: Boundary, vel, scalars, flags, jets: list, material, gravity: list[float]
    ) -> None:
        self.layout, self.f, self.bc = layout, f, bc
        self.vel, self.scalars, self.flags = vel, scalars, flags  # scalars: 0 smoke density, 1 temperature
        self.jets = list(jets)
        self.material = material
        dim = layout.dim
        self.n_jets = len(self.jets)
        self.npf = np.float64 if f == ti.f64 else np.float32
        self.jet_rows = np.zeros((max(1, self.n_jets), jet_row_width(dim)), dtype=self.npf)
        # run-time parameters: decay, cooling, alpha, beta, T_ambient, confinement epsilon
        self.params = ti.field(f, shape=6)
        self.dt = ti.field(f, shape=())
        self.jet_f = ti.field(f, shape=self.jet_rows.shape)  # this substep's jets (from the kernel argument)
        self.gravity = ti.Vector.field(dim, f, shape=())
        m = material
        self.params.from_numpy(
            np.array(
                [
                    m.decay,
                    m.cooling,
                    m.buoyancy,
                    m.thermal_expansion,
                    m.ambient_temperature,
                    m.vorticity_confinement,
                ],
                dtype=self.npf,
            )
        )
        self.gravity[None] = [float(g) for g in gravity]
        self.confine = m.vorticity_confinement > 0
        self.buoyant = m.buoyancy != 0 or m.thermal_expansion != 0
        if self.confine:
            nw = 3 if dim == 3 else 1
            shape = tuple(c + 2 for c in layout.n)
            self.omega = ti.Vector.field(nw, f, shape=shape, offset=(-1,) * dim)
            self.conf = ti.Vector.field(dim, f, shape=shape, offset=(-1,) * dim)
        self._make()

    def jet_arg(self, t: float) -> np.ndarray:
        """The per-jet row of the kernel argument at time t (host side; no device traffic)."""
        dim = self.layout.dim
        for k, jet in enumerate(self.jets):
            p, v, F, on = jet.state(t, dim)
            row = self.jet_rows[k]
            row[0:dim] = p
            row[dim : 2 * dim] = v
            row[2 * dim : 3 * dim] = on * F
            row[3 * dim] = jet.radius
            row[3 * dim + 1] = on * jet.density_rate
            row[3 * dim + 2] = on * jet.temperature_rate
            row[3 * dim + 3] = on if jet.velocity is not None else 0.0
        return self.jet_rows

    def _make(self) -> None:
        L, f, bc = self.layout, self.f, self.bc
        dim, n = L.dim, L.n
        vel, S, flags, params, gravity = self.vel, self.scalars, self.flags, self.params, self.gravity
        at = bc.at
        n_jets = self.n_jets
        any_vel = any(j.velocity is not None for j in self.jets)
        any_force = any(j.force is not None for j in self.jets)
        confine, buoyant = self.confine, self.buoyant
        origin = [float(o) for o in L.origin]
        dx = [float(h) for h in L.dx]
        h = min(dx)
        cells = bc.cells
        omega = self.omega if confine else None
        conf = self.conf if confine else None

        @ti.func
        def position(I, d):
            """World position of cell I (d = -1) or of face I of component d."""
            x = ti.Vector.zero(f, dim)
            for a in ti.static(range(dim)):
                x[a] = origin[a] + (I[a] + ti.select(a == d, 0.0, 0.5)) * dx[a]
            return x

        jf, dtf = self.jet_f, self.dt

        @ti.func
        def coverage(jets: ti.template(), k, x):
            """Fraction of the cell at x inside jet k: 1 inside, 0 outside, linear over one cell."""
            r2 = ti.cast(0.0, f)
            for a in ti.static(range(dim)):
                r2 += (x[a] - jets[k, a]) ** 2
            return ti.min(ti.max((jets[k, 3 * dim] - ti.sqrt(r2)) / h + 0.5, 0.0), 1.0)

        @ti.func
        def scalar_body(I):
            dt = dtf[None]
            decay = ti.exp(-params[0] * dt)
            cool = ti.exp(-params[1] * dt)
            Ta = params[4]
            si = S[at(0, I)]
            Ti = S[at(1, I)]
            if ti.static(n_jets > 0):
                x = position(I, -1)
                for k in range(n_jets):
                    c = coverage(jf, k, x)
                    si += dt * c * jf[k, 3 * dim + 1]
                    Ti += dt * c * jf[k, 3 * dim + 2]
            si *= decay
            Ti = Ta + (Ti - Ta) * cool
            if flags[I] == SOLID:
                si = 0.0
                Ti = Ta
            S[at(0, I)] = si
            S[at(1, I)] = Ti

        @ti.func
        def cell_velocity(I):
            v = ti.Vector.zero(f, dim)
            for a in ti.static(range(dim)):
                J = I
                J[a] += 1
                v[a] = 0.5 * (vel[at(a, I)] + vel[at(a, J)])
            return v

        @ti.func
        def clamp_cell(I):
            for a in ti.static(range(dim)):
                I[a] = ti.min(ti.max(I[a], 0), n[a] - 1)
            return I

        @ti.func
        def grad_velocity(I, a: ti.template()):
            """d u / d x_a at cell I (central difference of cell-centred velocities, one-sided at walls)."""
            Ip = clamp_cell(I + ti.Vector.unit(dim, a, ti.i32))
            Im = clamp_cell(I - ti.Vector.unit(dim, a, ti.i32))
            return (cell_velocity(Ip) - cell_velocity(Im)) / (ti.max(Ip[a] - Im[a], 1) * dx[a])

        @ti.func
        def vorticity_forces():
            for I in ti.grouped(ti.ndrange(*cells)):
                gx = grad_velocity(I, 0)
                gy = grad_velocity(I, 1)
                if ti.static(dim == 3):
                    gz = grad_velocity(I, 2)
                    omega[I] = ti.Vector([gy[2] - gz[1], gz[0] - gx[2], gx[1] - gy[0]])
                else:
                    omega[I] = ti.Vector([gx[1] - gy[0]])
            for I in ti.grouped(ti.ndrange(*cells)):
                g = ti.Vector.zero(f, dim)
                for a in ti.static(range(dim)):
                    Ip = clamp_cell(I + ti.Vector.unit(dim, a, ti.i32))
                    Im = clamp_cell(I - ti.Vector.unit(dim, a, ti.i32))
                    g[a] = (omega[Ip].norm() - omega[Im].norm()) / (ti.max(Ip[a] - Im[a], 1) * dx[a])
                N = g / (g.norm() + 1e-20)
                w = omega[I]
                if ti.static(dim == 3):
                    conf[I] = params[5] * h * N.cross(w)
                else:
                    conf[I] = params[5] * h * ti.Vector([N[1] * w[0], -N[0] * w[0]])

        def force_body(d):
            @ti.func
            def body(I):
                dt = dtf[None]
                J = at(d, I)
                u = vel[J]
                Lc = I
                Lc[d] -= 1
                if ti.static(buoyant):
                    sf = 0.5 * (S[at(0, Lc)] + S[at(0, I)])
                    Tf = 0.5 * (S[at(1, Lc)] + S[at(1, I)])
                    u += dt * (params[2] * sf - params[3] * (Tf - params[4])) * gravity[None][d]
                if ti.static(confine):
                    u += dt * 0.5 * (conf[clamp_cell(Lc)][d] + conf[clamp_cell(I)][d])
                if ti.static(n_jets > 0 and (any_vel or any_force)):
                    x = position(I, d)
                    for k in range(n_jets):
                        c = coverage(jf, k, x)
                        if ti.static(any_force):
                            u += dt * c * jf[k, 2 * dim + d]
                        if ti.static(any_vel):
                            u += c * jf[k, 3 * dim + 3] * (jf[k, dim + d] - u)
                vel[J] = bc.fixed_value(d, I, u)

            return body

        forces = bc.per_component(force_body)
        cell_loop = bc.cell_loops[0]
        width = self.jet_rows.shape[1]

        @ti.func
        def stages(dt):
            dtf[None] = dt
            cell_loop(scalar_body)
            if ti.static(confine):
                vorticity_forces()
            bc.each_face(forces)
            bc.fill_face_ghosts(vel)
            bc.fill_cell_ghosts(S, 2)

        if n_jets > 0:

            @ti.kernel
            def add_sources(dt: f, jets: ti.types.ndarray()):
                for k, j in ti.ndrange(n_jets, width):
                    jf[k, j] = jets[k, j]
                stages(dt)
        else:

            @ti.kernel
            def add_sources(dt: f):
                stages(dt)

        self._kernel = add_sources

    def __call__(self, dt: float, t: float) -> None:
        if self.n_jets:
            self._kernel(dt, self.jet_arg(t))
        else:
            self._kernel(dt)
