"""Per-frame and per-check kernels outside the substep: the runner's frame check (largest speed and
non-finite particles per body), the density pass alone (before the first substep, after a resume) and
stable_dt's inputs."""

from simcli.backend import stdout_to_stderr
from simcli.solvers.sph.bundle import SPHFields, SPHFuncs, SPHParams
from simcli.solvers.taichi_funcs import make_body_of, make_finite

with stdout_to_stderr():
    import taichi as ti


def make_outputs(P: SPHParams, F: SPHFields, fn: SPHFuncs, nbodies: int, deformable=None):
    """``(frame_stats, density_only, dt_stats)`` kernels; needs ``fn.neighbours_density`` (and
    ``fn.move_boundary`` with a moving boundary). ``deformable``: a DeformableBoundary (deformable.py) whose
    samples' speed dt_stats counts too, or None."""
    nb = nbodies
    x, v, rho, mid, mat_rho0 = F.x, F.v, F.rho, F.mid, F.mat_rho0
    body_offsets, stat_speed, stat_bad, pid = F.body_offsets, F.stat_speed, F.stat_bad, F.pid
    N = fn.count
    f64 = P.f == ti.f64
    neighbours_density = fn.neighbours_density
    moving_boundary = P.moving_boundary

    finite = make_finite(f64)

    body_of = make_body_of(nb, body_offsets)

    @ti.kernel
    def frame_stats():
        for b in range(nb):
            stat_speed[b] = 0.0
            stat_bad[b] = 0
        for i in range(N()):
            b = body_of(pid[i])
            vi = v[i]
            if finite(x[i]) and finite(vi):
                ti.atomic_max(stat_speed[b], vi.norm())
            else:
                ti.atomic_add(stat_bad[b], 1)

    @ti.kernel
    def density_only():
        if ti.static(moving_boundary):
            fn.move_boundary()
        fn.sort(N())
        for i in range(N()):
            neighbours_density(i)

    stat_dt = F.stat_dt
    wcsph = P.pressure_solver == "WCSPH"
    db = deformable
    has_db = db is not None
    n_db = db.n if has_db else 0

    @ti.kernel
    def dt_stats():
        """stable_dt's inputs in one launch (before every substep with sim.auto_check: substep): the
        largest finite particle speed (a deformable body's samples' included: its surface must not cross more
        than cfl ps in a substep either), and for WCSPH the largest rho / rho0 (global reductions, cheaper
        than frame_stats' per-body atomics)."""
        stat_dt[0] = 0.0
        stat_dt[1] = 0.0
        for i in range(N()):
            vi = v[i]
            if finite(vi):
                ti.atomic_max(stat_dt[0], vi.norm())
            if ti.static(wcsph):
                ti.atomic_max(stat_dt[1], rho[i] / mat_rho0[mid[i]])
        if ti.static(has_db):
            for s in range(n_db):
                vs = db.sv[s]
                if finite(vs):
                    ti.atomic_max(stat_dt[0], vs.norm())

    return frame_stats, density_only, dt_stats
