"""Small Taichi functions shared by solver families: the per-frame checks, and the Jacobi rotation of
the 3x3 eigen-solvers (FEM hessian projection, MPM plasticity).

Built by factories because they close over compile-time constants (the float type, the body
offsets of a solver's particle arrays).
"""

from simcli.backend import stdout_to_stderr

with stdout_to_stderr():
    import taichi as ti


def make_finite(f64: bool):
    """``finite(v)``: True when no component of vector ``v`` is inf or NaN. A bit test of the
    exponent (all ones = inf or NaN), because fast-math may fold ``isnan`` away."""

    @ti.func
    def finite(a):
        ok = True
        for d in ti.static(range(a.n)):
            if ti.static(f64):
                ok = ok and ((ti.bit_cast(a[d], ti.i64) >> 52) & 0x7FF) != 0x7FF
            else:
                ok = ok and ((ti.bit_cast(a[d], ti.i32) >> 23) & 0xFF) != 0xFF
        return ok

    return finite


def make_body_of(nb: int, body_offsets):
    """``body_of(p)``: the body (entity) that item ``p`` belongs to, by bisection over the
    ascending first-item offsets ``body_offsets`` (an i32 field of ``nb`` entries)."""

    @ti.func
    def body_of(p):
        lo = 0
        if ti.static(nb > 1):
            hi = nb
            while hi - lo > 1:
                m = (lo + hi) // 2
                if body_offsets[m] <= p:
                    lo = m
                else:
                    hi = m
        return lo

    return body_of


def make_body_frame_stats(nb: int, body_off, x, v, stat_speed, stat_bad, f64: bool):
    """The per-frame check of a solver whose bodies are contiguous ranges [body_off[b], body_off[b + 1])
    of its position and velocity fields: the largest speed and the count of non-finite entries per body."""
    finite = make_finite(f64)

    @ti.kernel
    def frame_stats():
        for b in range(nb):
            stat_speed[b] = 0.0
            stat_bad[b] = 0
        for b in range(nb):
            for i in range(body_off[b], body_off[b + 1]):
                if finite(x[i]) and finite(v[i]):
                    stat_speed[b] = ti.max(stat_speed[b], v[i].norm())
                else:
                    stat_bad[b] += 1

    return frame_stats


@ti.func
def jacobi_rotation(app, aqq, apq):
    """(t, c, s) of the Jacobi rotation that zeroes a symmetric matrix's (p, q) entry (Golub & Van Loan,
    Matrix Computations, sec. 8.5): t = tan of the angle, the smaller root (the stable choice), c = cos,
    s = sin. apq must not be zero."""
    theta = (aqq - app) / (2.0 * apq)
    t = 1.0 / (ti.abs(theta) + ti.sqrt(theta * theta + 1.0))
    if theta < 0.0:
        t = -t
    c = 1.0 / ti.sqrt(t * t + 1.0)
    return t, c, t * c
