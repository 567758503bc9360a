"""advect: symplectic Euler's position update, x += dt v (plus the shifting displacement), then the guards:
clamp to the domain, or `wall_standoff` inside it (dropping the velocity into the wall), and push out of
colliders (boundary.make_pushout).
"""

from simcli.backend import stdout_to_stderr
from simcli.solvers.sph.bundle import SPHFields, SPHFuncs, SPHParams

with stdout_to_stderr():
    import taichi as ti


def make_advect(P: SPHParams, F: SPHFields, fn: SPHFuncs):
    """``advect(i, vi, dt)``, a Taichi func: particle i moves with velocity vi, which it keeps (guarded)."""
    dim, f = P.dim, P.f
    x, v, shift = F.x, F.v, F.shift
    has_shift = shift is not None
    pushout = fn.pushout
    # the guard's faces: the domain walls, or wall_standoff inside them
    dom_lo = ti.Vector([a + P.wall_standoff for a in P.domain_lo], dt=f)
    dom_hi = ti.Vector([a - P.wall_standoff for a in P.domain_hi], dt=f)

    @ti.func
    def advect(i, vi, dt):
        """x += dt v; then the guards: clamp to the domain, push out of colliders."""
        xi = x[i] + dt * vi
        if ti.static(has_shift):
            xi += shift[i]
        for d in ti.static(range(dim)):
            if xi[d] < dom_lo[d]:
                xi[d] = dom_lo[d]
                vi[d] = ti.max(vi[d], 0.0)
            elif xi[d] > dom_hi[d]:
                xi[d] = dom_hi[d]
                vi[d] = ti.min(vi[d], 0.0)
        xi, vi = pushout(xi, vi)
        x[i] = xi
        v[i] = vi

    return advect
